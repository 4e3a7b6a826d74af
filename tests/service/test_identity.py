"""One identity of rig and patient per session, used by every store (issue 47 item 3): a table or an
assistance learned with one patient is never used with another, a simulated patient and none included;
metadata names the identity."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from rehab_hil.patient.profile import load_patient
from rehab_hil.profiles import load_profile
from rehab_hil.service.assist_store import AssistanceStore
from rehab_hil.service.identity import NO_PATIENT, SessionIdentity, store_name
from rehab_hil.service.rig_learning import TableStore
from rehab_hil.service.session import open_session
from rehab_hil.testing import CONFIGS

SMA = CONFIGS / "sma_exoskeleton.toml"
FE = CONFIGS / "finger_extensor.toml"
SIM = CONFIGS.parent / "profiles" / "sim"
EXAMPLE = CONFIGS.parent / "profiles" / "example.toml"


def identities(tmp_path: Path) -> dict[str, SessionIdentity]:
    """The same rig with every kind of patient, and the same patients on a simulated rig of another plant file."""
    twin = tmp_path / "capable_copy.toml"  # the same patient_id in another file: another simulated patient
    twin.write_text((SIM / "capable.toml").read_text() + "\n# edited\n")
    capable, weak = load_patient(SIM / "capable.toml"), load_patient(SIM / "weak.toml")
    prof = load_profile(EXAMPLE)
    rig_file = tmp_path / "rig.toml"
    rig_file.write_text(SMA.read_text())
    return {
        "none": SessionIdentity.of("rig-a"),
        "sim capable": SessionIdentity.of("rig-a", sim_patient=capable, sim_patient_path=SIM / "capable.toml"),
        "sim capable, another file": SessionIdentity.of("rig-a", sim_patient=load_patient(twin), sim_patient_path=twin),
        "sim weak": SessionIdentity.of("rig-a", sim_patient=weak, sim_patient_path=SIM / "weak.toml"),
        "profile": SessionIdentity.of("rig-a", profile=prof),
        "profile and sim capable": SessionIdentity.of("rig-a", profile=prof, sim_patient=capable,
                                                       sim_patient_path=SIM / "capable.toml"),
        "simulated rig": SessionIdentity.of("rig-a", sim_plant=rig_file),
        "rig a (space)": SessionIdentity.of("rig a"),
    }


def test_every_patient_and_rig_has_a_store_of_its_own_in_both_stores(tmp_path: Path) -> None:
    ids = identities(tmp_path)
    tables = {k: TableStore(tmp_path, i.rig, i.patient, "plan").path for k, i in ids.items()}
    kept = {k: AssistanceStore(tmp_path, i.rig, i.patient, "c", {}).path for k, i in ids.items()}
    for paths in (tables, kept):
        assert len(set(paths.values())) == len(paths), paths  # no two identities share a file
    assert ids["none"].patient is None and tables["none"].name.startswith(NO_PATIENT + "-")
    # a patient whose id reads like nobody's still has a store of its own
    assert store_name("no-patient") != store_name(None) and store_name("a b") != store_name("a-b")
    assert ids["profile and sim capable"].patient.startswith(load_profile(EXAMPLE).patient_id + "+sim-")


def learned(tmp_path: Path, patient: str | None, duration_s: float) -> dict:
    """The shipped SMA session on one rig id, learning on the rig, with a simulated patient (or none)."""
    sim = SIM / f"{patient}.toml" if patient else None
    with open_session(SMA, "inprocess", rig_id="rig-a", sim_patient=sim, learning_store=tmp_path / "tables",
                      record=tmp_path / "runs") as s:
        r = s.run(duration_s)
        table = s.controller.learned_table.copy()
        meta = json.loads((s.run_dir / "metadata.json").read_text())
    assert r.events == [], r.events
    return {**r.learning, "table": table, "identity": meta["identity"]}


@pytest.mark.slow
def test_a_table_learned_with_one_patient_starts_no_session_with_another_or_with_none(tmp_path: Path) -> None:
    first = learned(tmp_path, "capable", 20.0)  # one update, swapped in at 14.4 s, stored
    assert first["updates"] == 1 and Path(first["store"]).exists()
    assert first["identity"]["patient"].startswith("sim-sim-capable-") and first["identity"]["rig"] == "rig-a"
    for other in ("weak", None):
        got = learned(tmp_path, other, 5.0)
        assert not got["resumed"] and got["trials"] == 0 and got["store"] != first["store"], other
    again = learned(tmp_path, "capable", 5.0)
    assert again["resumed"] and again["store"] == first["store"]
    np.testing.assert_array_equal(again["table"], first["table"])


def kept(tmp_path: Path, patient: str | None) -> dict:
    sim = SIM / f"{patient}.toml" if patient else None
    with open_session(FE, "inprocess", controller="assist_as_needed", rig_id="rig-a", sim_patient=sim,
                      assistance_store=tmp_path / "kept") as s:
        r = s.run(18.0)  # the first open-close cycle: both moves learned
    return r.assistance


@pytest.mark.slow
def test_an_assistance_learned_with_a_simulated_patient_starts_no_session_without_one(tmp_path: Path) -> None:
    first = kept(tmp_path, "capable")
    a0 = first["start"]["open"]  # the config's initial_assistance
    assert first["end"]["open"] < a0 and Path(first["store"]).exists()
    nobody = kept(tmp_path, None)
    assert not nobody["resumed"] and nobody["start"] == first["start"]
    assert nobody["store"] != first["store"]
    again = kept(tmp_path, "capable")
    assert again["resumed"] and again["start"] == first["end"]
