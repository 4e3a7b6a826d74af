"""The cohort file: read and validated (one line naming the file and the key), and sampled
reproducibly, each draw following its distribution and the correlations over a few thousand patients."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from rehab_hil.config import ConfigError
from rehab_hil.patient.profile import load_patient
from rehab_hil.trial.cohort import load_cohort
from rehab_hil.trial.patient_run import profile_toml

ROOT = Path(__file__).resolve().parents[2]
SHIPPED = ROOT / "profiles" / "sim" / "cohort.toml"
N = 4000

TEST_COHORT = """
cohort_id = "test"

[[correlations]]
between = ["voluntary.flexion_capacity_nm", "voluntary.extension_capacity_nm"]
rho = 0.7

[strata.a]
share = 0.25
fugl_meyer_ue = [0, 25]
centre = "{centre}"

[strata.a.voluntary]
flexion_capacity_nm = {{ dist = "lognormal", median = 0.5, sigma_log = 0.4 }}
extension_capacity_nm = {{ dist = "lognormal", median = 0.2, sigma_log = 0.5 }}
stiffness_nm_per_rad = {{ dist = "around", relative_sd = 0.1 }}

[strata.a.cue]
reaction_s = {{ dist = "normal", mean = 0.3, sd = 0.05 }}

[strata.a.fatigue]
prevalence = 0.4
fatigue_per_s = {{ dist = "uniform", low = 0.01, high = 0.05 }}
recovery_per_s = 0.00134

[strata.b]
share = 0.75
centre = "{centre}"
"""


def _cohort(tmp_path: Path, text: str, name: str = "cohort.toml") -> Path:
    path = tmp_path / name
    path.write_text(text.format(centre=ROOT / "profiles" / "sim" / "weak.toml"))
    return path


def test_the_shipped_cohort_loads_and_every_drawn_patient_is_a_valid_profile(tmp_path):
    cohort = load_cohort(SHIPPED)
    assert [s.name for s in cohort.strata] == ["mild", "moderate", "severe"]
    assert [s.fugl_meyer_ue for s in cohort.strata] == [(51, 66), (26, 50), (0, 25)]
    for i in range(30):
        p = cohort.sample(7, i)
        path = tmp_path / f"{p.patient_id}.toml"
        path.write_text(profile_toml(p.profile, "drawn"))
        back = load_patient(path)  # the file a session reads
        assert back.patient_id == f"stroke-fma-{p.patient_id}"
        assert back.voluntary.flexion_capacity_nm == pytest.approx(p.parameters["voluntary.flexion_capacity_nm"])
        assert (back.spasticity is not None) == ("spasticity" in p.traits)


def test_a_patient_is_the_same_for_the_same_seed_and_index_whatever_else_was_drawn():
    cohort = load_cohort(SHIPPED)
    first = cohort.sample(42, 17)
    for i in range(17):
        cohort.sample(42, i)
    assert cohort.sample(42, 17) == first
    assert cohort.sample(43, 17).parameters != first.parameters
    assert cohort.sample(42, 18).parameters != first.parameters


def test_draws_follow_their_distributions_the_shares_and_the_correlation(tmp_path):
    cohort = load_cohort(_cohort(tmp_path, TEST_COHORT))
    patients = [cohort.sample(1, i) for i in range(N)]
    a = [p for p in patients if p.stratum == "a"]
    assert len(a) / N == pytest.approx(0.25, abs=4 * math.sqrt(0.25 * 0.75 / N))
    flex = np.log([p.parameters["voluntary.flexion_capacity_nm"] for p in a])
    ext = np.log([p.parameters["voluntary.extension_capacity_nm"] for p in a])
    n = len(a)
    assert np.mean(flex) == pytest.approx(math.log(0.5), abs=4 * 0.4 / math.sqrt(n))
    assert np.std(flex) == pytest.approx(0.4, rel=0.08)
    assert np.std(ext) == pytest.approx(0.5, rel=0.08)
    assert np.corrcoef(flex, ext)[0, 1] == pytest.approx(0.7, abs=0.05)
    stiff = np.array([p.parameters["voluntary.stiffness_nm_per_rad"] for p in a])  # around weak.toml's 3.0
    assert np.mean(stiff) == pytest.approx(3.0, abs=0.02) and np.std(stiff) == pytest.approx(0.3, rel=0.08)
    react = np.array([p.parameters["cue.reaction_s"] for p in a])
    assert np.mean(react) == pytest.approx(0.3, abs=0.005) and np.std(react) == pytest.approx(0.05, rel=0.08)
    tired = [p for p in a if "fatigue" in p.traits]
    assert len(tired) / n == pytest.approx(0.4, abs=4 * math.sqrt(0.4 * 0.6 / n))
    f = np.array([p.parameters["fatigue.fatigue_per_s"] for p in tired])
    assert f.min() >= 0.01 and f.max() <= 0.05 and np.mean(f) == pytest.approx(0.03, abs=0.001)
    b = [p for p in patients if p.stratum == "b"]  # the centre profile itself: weak.toml's values, none drawn
    assert {p.parameters["voluntary.flexion_capacity_nm"] for p in b} == {0.25}


def test_the_shipped_cohort_correlates_flexion_and_extension_within_each_stratum():
    cohort = load_cohort(SHIPPED)
    patients = [cohort.sample(3, i) for i in range(N)]
    for s in cohort.strata:
        group = [p.parameters for p in patients if p.stratum == s.name]
        assert len(group) / N == pytest.approx(s.share, abs=0.03)
        flex = np.log([g["voluntary.flexion_capacity_nm"] for g in group])
        ext = np.log([g["voluntary.extension_capacity_nm"] for g in group])
        assert np.corrcoef(flex, ext)[0, 1] == pytest.approx(0.6, abs=0.08)  # clipping at max moves it a little
    mild = [p for p in patients if p.stratum == "mild"]
    assert max(p.parameters["voluntary.flexion_capacity_nm"] for p in mild) <= 3.0  # max = 3.0 clips


@pytest.mark.parametrize(("change", "key", "words"), [
    (("[strata.b]\nshare = 0.75", "[strata.b]\nshare = 0.7"), "strata", "sum to 1"),
    (("median = 0.5, sigma_log", "medain = 0.5, sigma_log"), "strata.a.voluntary.flexion_capacity_nm.medain",
     "did you mean 'median'"),
    ((", sd = 0.05 }", " }"), "strata.a.cue.reaction_s", "needs sd"),
    (('dist = "normal"', 'dist = "gauss"'), "strata.a.cue.reaction_s.dist", "must be one of"),
    (("rho = 0.7", "rho = 1.2"), "correlations[0].rho", "(-1, 1)"),
    (('"voluntary.extension_capacity_nm"]', '"voluntary.extension_capacty_nm"]'), "correlations[0].between",
     "not a patient parameter"),
    (("prevalence = 0.4", "prevalence = 1.4"), "strata.a.fatigue.prevalence", "[0, 1]"),
    (("recovery_per_s = 0.00134", "recovery_per_s = -1.0"), "strata.a.fatigue.recovery_per_s", "greater than"),
    (("[strata.a.cue]", "[strata.a.cues]"), "strata.a.cues", "did you mean 'cue'"),
    (("sigma_log = 0.4 }", "sigma_log = -0.4 }"), "strata.a.voluntary.flexion_capacity_nm.sigma_log", "at least 0"),
    (("fugl_meyer_ue = [0, 25]", "fugl_meyer_ue = [0, 80]"), "strata.a.fugl_meyer_ue", "0..66"),
])
def test_a_bad_cohort_is_one_line_naming_the_file_and_the_key(tmp_path, change, key, words):
    text = TEST_COHORT.replace(*change)
    assert text != TEST_COHORT
    path = _cohort(tmp_path, text)
    with pytest.raises(ConfigError) as e:
        load_cohort(path)
    msg = str(e.value)
    assert "\n" not in msg and msg.startswith(f"{path}: {key}: ") and words in msg, msg


def test_correlations_no_cohort_could_have_are_refused(tmp_path):
    three = TEST_COHORT.replace("[strata.a]", """[[correlations]]
between = ["voluntary.flexion_capacity_nm", "voluntary.stiffness_nm_per_rad"]
rho = 0.9

[[correlations]]
between = ["voluntary.extension_capacity_nm", "voluntary.stiffness_nm_per_rad"]
rho = -0.9

[strata.a]""")
    with pytest.raises(ConfigError, match=r"correlations: .*not positive definite"):
        load_cohort(_cohort(tmp_path, three))
    fixed = TEST_COHORT.replace('["voluntary.flexion_capacity_nm", "voluntary.extension_capacity_nm"]',
                                '["voluntary.flexion_capacity_nm", "voluntary.damping_nm_s_per_rad"]')
    with pytest.raises(ConfigError, match=r"correlations\[0\].between: voluntary.damping_nm_s_per_rad is drawn in no"):
        load_cohort(_cohort(tmp_path, fixed))
