"""The shipped simulated patients load, say where each value comes from, and recover across sessions."""

from __future__ import annotations

import re

import pytest

from rehab_hil.config import ConfigError
from rehab_hil.patient.profile import load_patient
from tests.conftest import ROOT

SIM = ROOT / "profiles" / "sim"


@pytest.mark.parametrize("name", ["capable", "weak", "fatiguing", "slacking", "spastic", "passive"])
def test_each_shipped_patient_loads_and_every_value_has_its_source_in_a_comment(name):
    path = SIM / f"{name}.toml"
    load_patient(path)
    for line in path.read_text().splitlines():
        if re.match(r"^\s*[a-z_]+\s*=\s*[-0-9.]", line):
            assert "#" in line, f"{path.name}: {line!r} has no comment"


def test_recovery_grows_the_capacity_per_session_up_to_its_ceiling(tmp_path):
    text = (SIM / "weak.toml").read_text() + ("\n[recovery]\nsessions_done = 10\ncapacity_gain_per_session = 0.1\n"
                                              "capacity_ceiling_nm = 0.5\n")
    path = tmp_path / "recovering.toml"
    path.write_text(text)
    flex, ext = load_patient(path).capacity_nm()
    assert flex == 0.5  # 0.25 x 1.1^10 = 0.65, held at the ceiling
    assert ext == pytest.approx(0.06 * 1.1**10)


def test_a_trait_with_a_bad_value_names_the_file_and_the_key(tmp_path):
    path = tmp_path / "bad.toml"
    path.write_text((SIM / "spastic.toml").read_text().replace("delay_s = 0.04", "delay_s = 0.5"))
    with pytest.raises(ConfigError, match=r"bad.toml: spasticity.delay_s"):
        load_patient(path)
