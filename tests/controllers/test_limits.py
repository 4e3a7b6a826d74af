"""Limits every controller respects (issue 39 item 3): no controller plans or commands continuous
heating beyond ``max_heating_s`` less its margin, nor a temperature beyond its budget; the
pre-flight covers two cycles and the longest hold with the profile applied, and a refusal names the
file and the key behind it and what would pass."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from rehab_hil.controllers import build_controller, closed_loop
from rehab_hil.controllers.build import preflight_duration_s
from rehab_hil.controllers.limits import heating_limit_s
from rehab_hil.controllers.rig_learning import longest_run_s
from rehab_hil.interchange import read_csv
from rehab_hil.loading import load_config
from rehab_hil.service.session import SessionError, open_session
from rehab_hil.testing import CONFIGS

pytestmark = [pytest.mark.slow, pytest.mark.timeout(600)]


def longest_s(effort: np.ndarray, step_s: float) -> float:
    """The longest run of nonzero effort in a record (not wrapped: a record is no period)."""
    return longest_run_s(np.append(np.abs(effort) > 0, False), step_s)

SMA = CONFIGS / "sma_exoskeleton.toml"
EXAMPLE = CONFIGS.parent / "profiles" / "example.toml"


def test_every_controller_on_the_sma_plans_no_run_past_the_heating_limit(sma) -> None:
    for name in ("pid", "pulsed", "open_loop_map", "model_based", "assist_as_needed"):
        ctl = build_controller(sma, name)
        res = closed_loop(ctl, preflight_duration_s(ctl.reference))
        assert longest_s(res[ctl.ctx.effort], ctl.ctx.step_s) <= heating_limit_s(ctl.ctx), name


def test_the_preflight_covers_two_cycles_and_the_longest_hold(sma) -> None:
    ref = build_controller(sma, "pid").reference
    assert preflight_duration_s(ref) >= ref.first_open_s + 2 * ref.period_s + ref.hold_open_s


def test_pid_on_the_shipped_sma_config_runs_past_its_former_trip_without_one() -> None:
    with open_session(SMA, "inprocess", controller="pid") as s:  # it tripped heating_time at 19.8 s
        r = s.run(30.0)
    assert r.events == [] and r.pwm_off_at_end, r.events
    assert r.session_cycles and max(c["peak_temperature_c"] for c in r.session_cycles) <= 132.8


@pytest.mark.parametrize("controller", ["pid", "assist_as_needed"])
def test_a_tcp_coil_that_cannot_bend_a_passive_finger_is_held_below_its_temperature_trip(controller, tmp_path) -> None:
    """A passive patient's finger is 70 times what the TCP muscle can bend: the controller asks for
    more and more heat. Its ceiling reads the temperature the coil would still reach after a cut (TF_TP002
    hides 2.7 C/W in a fast mode), not the temperature: before, both controllers tripped at 180 C (24 s
    and 33 s in)."""
    with open_session(CONFIGS / "tcp_finger.toml", "inprocess", controller=controller,
                      sim_patient=CONFIGS.parent / "profiles" / "sim" / "passive.toml",
                      assistance_store=tmp_path / "store", record=tmp_path / "runs") as s:
        r = s.run(60.0)
        run_dir = s.run_dir
    assert r.events == [] and r.pwm_off_at_end, r.events
    temperature = read_csv(run_dir / "run.csv").signals["estimated_temperature_c"]
    limit = load_config(CONFIGS / "tcp_finger.toml").rig.limits.max_temperature_c
    assert limit - 20.0 < temperature.max() < limit  # it worked near the limit, and stayed below it


def test_the_example_profile_runs_with_the_shipped_sma_controller() -> None:
    with open_session(SMA, "inprocess", profile=EXAMPLE) as s:  # refused before: "heats continuously for 7.5 s"
        r = s.run(50.0)
    assert r.events == [], r.events
    assert len(r.session_cycles) >= 2 and max(c["rmse_deg"] for c in r.session_cycles) < 1.5


def test_a_refusal_names_the_profile_file_and_key_and_what_would_pass(tmp_path: Path) -> None:
    profile = tmp_path / "narrow.toml"
    profile.write_text('patient_id = "P-7"\n[session]\namplitude_deg = 20.0\n[limits]\nmax_angle_deg = 30.0\n')
    with pytest.raises(SessionError) as e:  # the pulses bend the finger to ~37 deg whatever the reference
        open_session(SMA, "inprocess", controller="pulsed", profile=profile)
    text = str(e.value)
    assert f"{profile}: limits.max_angle_deg" in text and "would pass: max_angle_deg >=" in text, text


def test_a_refusal_without_a_profile_names_the_config_file_and_key(tmp_path: Path) -> None:
    cfg = tmp_path / "sma.toml"
    cfg.write_text(SMA.read_text().replace("max_angle_deg = 90.0", "max_angle_deg = 32.0", 1).replace(
        "open_deg = 37.5                     # Fig. 7", "open_deg = 20.0  # Fig. 7", 1))
    with pytest.raises(SessionError) as e:
        open_session(cfg, "inprocess", controller="pulsed")
    assert f"{cfg}: rig.limits.max_angle_deg" in str(e.value), str(e.value)


def test_the_guard_rests_a_held_demand_before_the_supervisor_would_trip(sma) -> None:
    cfg = load_config(SMA)
    ctl = build_controller(cfg, "pulsed", check=False)  # 5 s pulses: lengthen one past the limit
    from rehab_hil.controllers.pulsed import Pulsed, PulsedSettings

    held = Pulsed.build(ctl.ctx, PulsedSettings(effort=0.3, on_s=60.0, off_s=1.0), ctl.reference)
    res = closed_loop(held, 20.0)
    on = np.abs(res[ctl.ctx.effort]) > 0
    assert on.mean() > 0.9  # it still drives nearly all the time ...
    assert longest_s(res[ctl.ctx.effort], ctl.ctx.step_s) <= heating_limit_s(ctl.ctx)  # ... in runs it accepts
