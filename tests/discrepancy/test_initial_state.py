"""Issue 14 item 1: the start state comes from the data, not from the config's rest state."""

from __future__ import annotations

import numpy as np
import pytest

from rehab_hil.discrepancy.initial_state import estimate_initial_state
from rehab_hil.discrepancy.replay import Replay


@pytest.fixture(scope="module")
def away(fe, independent):
    """8 s of independent closed-loop data whose iris starts well away from the config's rest (0)."""
    spec, cfg = fe
    for seed in range(20):
        rec = independent.fe_record({}, {}, seed, duration_s=8.0, rate_hz=1000.0)
        if rec.signals["iris_angle_deg"][0] > 15.0:
            return Replay.build(spec, cfg, rec)
    raise AssertionError("no start above 15 deg in 20 seeds")


def test_measured_outputs_set_their_states_and_the_rest_is_estimated(away):
    P = away.nominal_params()
    init = estimate_initial_state(away, P, away.t.size // 2)
    assert init.set_from_data["iris.angle_rad"] == "iris_angle_deg"
    assert init.set_from_data["motor.current_a"] == "motor_current_a"
    assert np.degrees(away.x0[0]) == pytest.approx(away.measured["iris_angle_deg"][0], abs=0.2)
    assert "iris.velocity_rad_s" in init.estimated
    text = "\n".join(init.describe())
    assert "iris.angle_rad" in text and "estimated" in text


def test_starting_from_the_data_removes_the_offset_of_the_rest_start(away):
    P = away.nominal_params()
    n = away.t.size
    away.x0, away.xd0 = away.system.x0.copy(), away.system.xd0.copy()  # the config's rest state
    rest = np.sqrt(np.mean(away.residual(away.simulate(P, mode="open"))[0] ** 2))
    estimate_initial_state(away, P, n // 2)
    start = np.sqrt(np.mean(away.residual(away.simulate(P, mode="open"))[0] ** 2))
    assert start < 0.5 * rest, (start, rest)
