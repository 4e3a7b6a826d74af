"""A record that starts at rest is replayed from rest (issue 38 item 5): said with ``--start rest``, or
found from the data when no channel moves in its first 50 ms; a record cut in mid-motion is not taken
for one at rest. A torque-commanded servo (plants/motor_axis.py), its angle logged alone."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from rehab_hil.discrepancy.initial_state import _back_to_rest, estimate_initial_state, starts_at_rest
from rehab_hil.discrepancy.replay import Replay
from rehab_hil.interchange import Recording
from rehab_hil.loading import load_config
from rehab_hil.plants import get_plant, run_scenario
from rehab_hil.plants.experiments import Scenario
from rehab_hil.testing import servo_axis_config

ROOT = Path(__file__).resolve().parents[2]


@pytest.fixture(scope="module")
def servo(tmp_path_factory):
    f = servo_axis_config(tmp_path_factory.mktemp("servo") / "servo.toml",
                          load="coulomb_nm = 0.02\nstick_velocity = 0.01\nstick_damping = 0.05")
    return get_plant("motor_axis"), load_config(f)


def _replay(servo, cut_s: float = 0.0, start: str = "auto") -> Replay:
    """6 s of torque steps from standstill (the first 0.3 s with no torque); ``cut_s`` drops the start,
    so the record begins in mid-motion. Angle only, with 1e-4 rad of encoder noise."""
    spec, cfg = servo
    n = 6000 + round(cut_s * 1000)
    t = np.arange(n) * 1e-3
    tau = np.where((t % 2) < 1, 0.06, -0.06) * (t > 0.3)
    res = run_scenario(spec, cfg, Scenario("steps", n, inputs={"drive_torque_nm": tau}))
    k = round(cut_s * 1000)
    angle = res["angle_deg"][k:] + np.degrees(np.random.default_rng(2).normal(0, 1e-4, n - k))
    rec = Recording(t[k:] - t[k], {"drive_torque_nm": tau[k:], "angle_deg": angle})
    replay = Replay.build(spec, cfg, rec, "servo.csv")
    replay.start = start
    return replay


def _velocity(replay: Replay) -> tuple[float, object]:
    init = estimate_initial_state(replay, replay.nominal_params(), 3600)
    names = replay.system.diagram.state_names
    return float(init.x0[names.index(next(n for n in names if "velocity" in n))]), init


def test_a_record_from_standstill_is_found_at_rest_and_a_start_velocity_that_would_show_goes_back_to_0(servo):
    replay = _replay(servo)
    assert starts_at_rest(replay)
    v, _init = _velocity(replay)
    assert abs(v) * 0.05 < 4 * 1e-4  # what the fit leaves cannot move the angle beyond its noise in 50 ms
    P = replay.nominal_params()
    names = replay.system.diagram.state_names
    vel = next(i for i, n in enumerate(names) if "velocity" in n)
    x, xd = replay.x0.copy(), replay.xd0.copy()
    x[vel] = 7.0  # what a nuisance fit gave a servo standing still (issue 38)
    assert _back_to_rest(replay, P, x, xd, [vel]) == "data" and x[vel] == 0.0
    x[vel] = 1e-4  # too small to show: left as fitted
    assert _back_to_rest(replay, P, x, xd, [vel]) == "" and x[vel] == 1e-4


def test_a_record_cut_in_mid_motion_is_not_taken_for_one_at_rest(servo):
    replay = _replay(servo, cut_s=1.5)  # 1.5 s in: turning at some rad/s
    assert not starts_at_rest(replay)
    v, init = _velocity(replay)
    assert init.at_rest == "" and abs(v) > 1.0


def test_start_rest_said_by_the_user_holds_every_unmeasured_state(servo):
    replay = _replay(servo, cut_s=1.5, start="rest")
    v, init = _velocity(replay)
    assert v == 0.0 and init.at_rest == "option" and init.estimated == {}
