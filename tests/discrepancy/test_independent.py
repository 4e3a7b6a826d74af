"""Issue 14 items 2, 3 and 5 on independent closed-loop records (bench/discrepancy.py's simulator):
a replay that does not drift, a parameter error reported as a parameter, two effects refitted jointly."""

from __future__ import annotations

import numpy as np
import pytest

from rehab_hil.discrepancy.initial_state import estimate_initial_state
from rehab_hil.discrepancy.replay import Replay
from rehab_hil.discrepancy.report import augmented_toml
from rehab_hil.discrepancy.shooting import choose_mode
from rehab_hil.discrepancy.workflow import Options, find_missing_effects
from rehab_hil.loading import load_config

from .conftest import FE_CONFIG


@pytest.fixture(scope="module")
def low_kt(independent):
    """Closed loop with the real torque constant 15 % below the config's: the open-loop replay drifts."""
    return independent.fe_record({}, {"kt": -0.15}, 4, duration_s=12.0, rate_hz=500.0)


def test_closed_loop_drift_is_detected_and_shooting_does_not_drift(fe, low_kt):
    spec, cfg = fe
    replay = Replay.build(spec, cfg, low_kt)
    P = replay.nominal_params()
    n = replay.t.size * 6 // 10
    estimate_initial_state(replay, P, n)
    mode, _, _ = choose_mode(replay, P, n)
    assert mode == "shooting"
    angle = [np.sqrt(np.mean(replay.residual(replay.simulate(P, n, mode=m), slice(0, n))[0] ** 2))
             for m in ("open", "shooting")]
    assert angle[1] < angle[0] / 3, angle


@pytest.mark.slow
def test_a_parameter_error_is_reported_as_the_parameter_with_its_corrected_config(fe, low_kt, tmp_path):
    _spec, cfg = fe
    res = find_missing_effects(cfg, low_kt, "kt.csv", options=Options(max_effects=2))
    assert res.named == [], res.conclusion
    kt = {f.effect: f for f in res.parameters}["motor.kt_nm_per_a"]
    assert kt.params["error_fraction"] == pytest.approx(-0.15, abs=0.15 * 0.15), res.conclusion
    assert "parameter motor.kt_nm_per_a is off by -1" in res.conclusion and "CI" in res.conclusion
    text = augmented_toml(res, FE_CONFIG)
    (tmp_path / "aug.toml").write_text(text)
    fixed = load_config(tmp_path / "aug.toml")
    assert fixed.motor.kt_nm_per_a == pytest.approx(0.791 * (1 + kt.params["error_fraction"]), rel=1e-9)
    assert not fixed.effects


@pytest.mark.slow
def test_two_effects_are_both_named_and_refitted_jointly(fe, independent):
    _spec, cfg = fe
    rec = independent.fe_record({"coulomb_friction": {"level_nm": 0.03}, "time_delay": {"delay_s": 0.015}}, {}, 5,
                                duration_s=12.0, rate_hz=1000.0)
    res = find_missing_effects(cfg, rec, "pair.csv", options=Options(max_effects=3))
    assert {"coulomb_friction", "time_delay"} <= set(res.named), res.conclusion
    fitted = {f.effect: f.params for f in res.chosen}
    assert fitted["coulomb_friction"]["level_nm"] == pytest.approx(0.03, rel=0.15)
    assert fitted["time_delay"]["delay_s"] == pytest.approx(0.015, abs=0.002)
    # one jointly refitted parameter vector carries both (not the first frozen, the second added on top)
    replay, P = res.extras["replay"], res.chosen[-1].P
    assert all(f.P is P for f in res.chosen)
    assert P[replay.index("coulomb_friction", "level_nm")] == fitted["coulomb_friction"]["level_nm"]
    assert P[replay.index("time_delay", "delay_s")] == fitted["time_delay"]["delay_s"]
    assert all(np.isfinite(v) for f in res.chosen for v in f.stderr.values())
