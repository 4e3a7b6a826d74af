"""The workflow on data with a hidden effect names it, recovers it and closes the gap; on clean
data it names nothing. Data: model WITH the effect, iris inertia +5 % (an unrelated mismatch),
0.01 A current noise, encoder quantisation (2000 counts/rev), logged at 800 Hz vs a 1 kHz model."""

from __future__ import annotations

import pytest

from rehab_hil.discrepancy.replay import Replay
from rehab_hil.discrepancy.synthetic import hidden_effect_recording
from rehab_hil.discrepancy.workflow import Options, find_missing_effects

# the module fixtures are built once: every test of the module runs on one xdist worker
pytestmark = pytest.mark.xdist_group("test_workflow")

# effect -> (true parameters, tolerance per parameter (absolute), least cut of the angle RMSE)
CASES = {
    "coulomb_friction": ({"level_nm": 0.03}, {"level_nm": 0.003}, 0.6),
    "viscous_friction": ({"damping_nm_s_per_rad": 0.025}, {"damping_nm_s_per_rad": 0.0025}, 0.6),
    "backlash": ({"width_rad": 0.035}, {"width_rad": 0.0035}, 0.6),
    "time_delay": ({"delay_s": 0.013}, {"delay_s": 0.0015}, 0.5),
    "contact_spring_damper": ({"stiffness_nm_per_rad": 0.8, "damping_nm_s_per_rad": 0.04, "contact_angle_rad": 0.55},
                              {"stiffness_nm_per_rad": 0.12, "damping_nm_s_per_rad": 0.015, "contact_angle_rad": 0.05},
                              0.6),
}
OPTIONS = Options(max_effects=2)


@pytest.fixture(scope="module")
def replay(fe):
    spec, cfg = fe
    rec = hidden_effect_recording(spec, cfg, {}, duration_s=3.0)
    return Replay.build(spec, cfg, rec)


@pytest.mark.slow
@pytest.mark.parametrize("effect", sorted(CASES))
def test_hidden_effect_is_named_first_recovered_and_the_gap_shrinks(fe, replay, effect):
    spec, cfg = fe
    true, tol, cut = CASES[effect]
    rec = hidden_effect_recording(spec, cfg, {effect: true}, duration_s=12.0, seed=7, replay=replay)
    res = find_missing_effects(cfg, rec, "hidden.csv", options=OPTIONS)
    assert res.named and res.named[0] == effect, [(c.fit.effect, c.delta_bic) for c in res.rounds[0].candidates]
    fitted = res.chosen[0].params
    for k, v in true.items():
        assert fitted[k] == pytest.approx(v, abs=tol[k]), (k, fitted[k], v)
    before, after = res.metrics("nominal", "holdout"), res.metrics("augmented", "holdout")
    assert after["iris_angle_deg"]["rmse"] <= (1 - cut) * before["iris_angle_deg"]["rmse"]


@pytest.mark.slow
@pytest.mark.parametrize("seed", [3, 11])
def test_clean_data_names_no_effect(fe, replay, seed):
    spec, cfg = fe
    rec = hidden_effect_recording(spec, cfg, {}, duration_s=12.0, seed=seed, replay=replay)
    res = find_missing_effects(cfg, rec, "clean.csv", options=OPTIONS)
    assert res.named == [], [(c.fit.effect, c.delta_bic, c.improvement) for c in res.rounds[0].candidates]
    assert res.rounds[0].chosen is None
