"""Issue 14 items 3-4: an unexplained residual is said so (never "fits"), and near-aliases are named
together with the experiment that would separate them."""

from __future__ import annotations

import numpy as np
import pytest

from rehab_hil.discrepancy.fitting import Fit
from rehab_hil.discrepancy.result import Alias, Result
from rehab_hil.discrepancy.verdict import experiment, is_alias, noise_floor, unexplained_channels
from rehab_hil.discrepancy.workflow import Options, find_missing_effects
from rehab_hil.interchange import Recording


def test_noise_floor_and_the_unexplained_threshold():
    rng = np.random.default_rng(0)
    t = np.linspace(0, 10, 5000)
    y = 20 * np.sin(t) + rng.normal(0, 0.1, t.size)
    assert noise_floor(y) == pytest.approx(0.1, rel=0.1)
    fast = 60 * np.sin(10 * t) + rng.normal(0, 0.1, t.size)  # 600 deg/s of motion is not noise
    assert noise_floor(fast) == pytest.approx(0.1, rel=0.2)
    assert unexplained_channels(["a"], {"a": y}, {"a": 0.2}) == {}  # at the noise: explained
    out = unexplained_channels(["a"], {"a": y}, {"a": 3.0})  # 20 % of the spread: not
    assert out["a"]["rms"] == 3.0 and out["a"]["threshold"] < 3.0


def test_aliases_within_the_margin_and_the_suggested_experiment():
    assert is_alias(-500.0, -495.0, 1.0, 1.5)  # BIC within the margin
    assert is_alias(-500.0, -300.0, 1.0, 1.05)  # same error where it matters
    assert not is_alias(-500.0, -300.0, 1.0, 2.0)
    # the fit part prefers the one the held-out part ranks second: the record's halves disagree
    assert is_alias(-500.0, -300.0, 1.0, 2.0, train_a=0.35, train_b=0.33)
    assert not is_alias(-500.0, -300.0, 1.0, 2.0, train_a=0.33, train_b=0.35)
    assert "the fit part prefers b" in Alias(1, "a", "b", 118.0, "x", split=True).sentence()
    assert "slow ramp through the contact angle" in experiment("passive_muscle", "contact_spring_damper", {})
    assert "a" in experiment("a", "b", {"a": "thing a", "b": "thing b"})


def _result(chosen, aliases=(), unexplained=None) -> Result:
    t = np.arange(3.0)
    return Result("p", ["y"], {"y": "angle"}, t, {"y": t}, {"y": t}, {"y": t}, list(chosen), [], 1.0, {"y": 1.0},
                  aliases=list(aliases), unexplained=unexplained or {},
                  unexplained_where={"region": "rest", "window_start_s": 0.0, "window_end_s": 1.0}
                  if unexplained else {})


def test_conclusion_sentences():
    par = Fit("motor.kt_nm_per_a", {"error_fraction": -0.15}, {"error_fraction": 0.01}, {}, 0.0, 1, np.zeros(1),
              "parameter")
    assert _result([par]).conclusion.startswith("parameter motor.kt_nm_per_a is off by -15.0 % (95 % CI -17.0 ..")
    assert _result([par]).named == []
    eff = Fit("passive_muscle", {"scale_nm": 0.01}, {"scale_nm": 0.001}, {}, 0.0, 1, np.zeros(1))
    al = Alias(1, "passive_muscle", "contact_spring_damper", 3.0, "a slow ramp")
    text = _result([eff], [al]).conclusion
    assert "missing effect found: passive_muscle" in text and "not distinguishable" in text and "slow ramp" in text
    text = _result([], unexplained={"y": {"rms": 3.0}}).conclusion
    assert text.startswith("unexplained residual on y") and "rest" in text
    assert "fits" in _result([]).conclusion


@pytest.mark.slow
def test_a_residual_nothing_explains_is_reported_unexplained_with_where_it_sits(fe, independent):
    _spec, cfg = fe
    rec = independent.fe_record({}, {}, 9, duration_s=10.0, rate_hz=1000.0)
    ang = rec.signals["iris_angle_deg"]
    # an out-of-library sensor fault: a slow wobble of the logged angle (a slipping encoder disc)
    wobbled = {**rec.signals, "iris_angle_deg": ang + 4.0 * np.sin(2 * np.pi * 0.37 * rec.t)}
    res = find_missing_effects(cfg, Recording(rec.t, wobbled), "wobble.csv", options=Options(max_effects=2))
    assert "iris_angle_deg" in res.unexplained, res.conclusion
    assert "unexplained residual" in res.conclusion and "fits" not in res.conclusion
    assert {"region", "window_start_s", "window_end_s"} <= set(res.unexplained_where)


# --- honest verdicts (issue 38 item 5) ---

def _noisy_result(offset: float, aliases=(), unexplained=None) -> Result:
    """A 20 s angle record with 0.1 deg of white noise; the final model is the noiseless motion plus
    ``offset`` (deg); held out from 12 s."""
    rng = np.random.default_rng(1)
    t = np.arange(0, 20, 0.001)
    clean = 30 * np.sin(0.5 * t)
    y = clean + rng.normal(0, 0.1, t.size)
    return Result("p", ["angle_deg"], {"angle_deg": "angle"}, t, {"angle_deg": y}, {"angle_deg": clean},
                  {"angle_deg": clean + offset}, [], [], 12.0, {"angle_deg": 1.0}, aliases=list(aliases),
                  unexplained=unexplained or {})


def test_a_fit_within_the_noise_is_said_only_at_the_noise_floor_with_both_figures():
    text = _noisy_result(0.0).conclusion
    assert text.startswith("no missing effect found: the model fits within the noise")
    assert "angle_deg residual 0.099 deg, noise floor 0.1 deg" in text


def test_a_residual_above_the_noise_floor_is_never_called_a_fit():
    text = _noisy_result(0.5).conclusion  # 0.51 deg RMS: five noise floors, 2.6 % of the spread
    assert "fits within the noise" not in text
    assert "above the noise floor" in text and "angle_deg (0.51 deg RMS, 2.6 % of its spread; noise floor 0.1 deg)" \
        in text


def test_an_unexplained_residual_gives_its_size_its_share_of_the_spread_and_the_noise_floor():
    text = _noisy_result(7.0, unexplained={"angle_deg": {"rms": 7.0}}).conclusion
    assert text.startswith("unexplained residual on angle_deg (7 deg RMS, 35 % of its spread; noise floor 0.1 deg)")


def test_alias_wording_follows_the_scores_and_each_pair_is_said_once():
    close = Alias(1, "coulomb_friction", "viscous_friction", 3.2, "several speeds")
    far = Alias(1, "viscous_friction", "coulomb_friction", 105.7, "several speeds")
    assert "explain the residual about equally" in close.sentence()
    assert "about equally" not in far.sentence()
    assert "scores clearly better than coulomb_friction (delta BIC +105.7)" in far.sentence()
    again = [Alias(r, "viscous_friction", "coulomb_friction", 105.7, "several speeds") for r in (1, 2, 3, 4, 5)]
    text = _noisy_result(0.0, again).conclusion
    assert text.count("scores clearly better") == 1  # five rounds, one sentence


def test_the_noise_floor_of_records_joined_end_to_end_is_their_noise_not_their_joins() -> None:
    rng = np.random.default_rng(3)
    ramps = [np.linspace(0.0, 400.0 * (i + 1), 20_000) + rng.normal(0.0, 0.01, 20_000) for i in range(4)]
    joined = np.concatenate(ramps)  # each record's angle starts again at 0
    assert noise_floor(ramps[0]) == pytest.approx(0.01, rel=0.1)
    assert noise_floor(joined) == pytest.approx(0.01, rel=0.1)  # was 4.6e2 deg on the servo bench's records
