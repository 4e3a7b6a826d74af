"""The safety's temperature estimate against the simulated rig's truth (issue 47 item 1), through
``open_session`` on the in-process rig (lockstep): the true wire temperature in ``sim_truth.csv`` with or
without a simulated patient; on rigs that differ from the config the way a lab's day does (room 16-40 C,
convection -30 %, supply +10 %; none of them tuned on) the estimate takes the twin's stricter values and
follows the truth from the twin's first window on, and never reads cooler than the truth where the rig is
cooler than the config (the twin's looser values are not taken)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from rehab_hil.patient.attach import TRUTH_SIGNALS
from rehab_hil.patient.truth import TRUTH_FILE, read_truth
from rehab_hil.service.session import open_session
from rehab_hil.testing import CONFIGS, config_with_lines

pytestmark = [pytest.mark.slow, pytest.mark.timeout(900)]

SMA = CONFIGS / "sma_exoskeleton.toml"
CAPABLE = CONFIGS.parent / "profiles" / "sim" / "capable.toml"
TARGET_C = 3.0  # issue 47: within 3 C of the simulated truth
TAKEN_MARGIN_S = 0.005  # the rows recorded at the cycle that took a tightening still hold the value before it


def rig(tmp_path: Path, old: str, new: str) -> Path:
    """The shipped SMA config with one line changed: the simulated rig's plant (``--sim-plant``)."""
    return config_with_lines(SMA, tmp_path / "rig.toml", {old: new})


def session(tmp_path: Path, duration_s: float, **options) -> dict:
    """A recorded session; its estimate beside its truth on the recording's time axis."""
    with open_session(SMA, "inprocess", record=tmp_path / "runs", **options) as s:
        result = s.run(duration_s)
        run_dir = s.run_dir
    rows = np.genfromtxt(run_dir / "run.csv", delimiter=",", names=True)
    truth = read_truth(run_dir / TRUTH_FILE)
    t = rows["time_s"]
    true = np.interp(t, truth["t_s"], truth["sma_temperature_c"])
    return {"result": result, "t": t, "estimate": rows["estimated_temperature_c"], "truth": true,
            "columns": list(truth), "metadata": json.loads((run_dir / "metadata.json").read_text())}


def test_a_simulated_rig_writes_its_true_wire_temperature_with_or_without_a_patient(tmp_path: Path) -> None:
    alone = session(tmp_path / "a", 9.0)
    assert alone["columns"] == ["t_s", "theta_mcp_rad", "omega_mcp_rad_s", "sma_temperature_c"]
    assert alone["metadata"]["sim_truth"] == TRUTH_FILE and alone["truth"].max() > 90.0  # the first bend
    gap = alone["estimate"] - alone["truth"]  # the config's own rig: the safety's model is the rig's
    assert np.abs(gap).max() < 0.3, np.abs(gap).max()
    patient = session(tmp_path / "b", 3.0, sim_patient=CAPABLE, controller="pid")
    assert patient["columns"][:4] == alone["columns"] and set(TRUTH_SIGNALS) <= set(patient["columns"])


# One rig per quantity the safety can take (issue 49 cut a 26 s session here: a room of 30 C, covered by
# "room 40 C", the same quantity taken the same way, and by tests/twin/test_thermal.py's warm-room test,
# where the twin finds that 30 C room within 2 C).
@pytest.mark.parametrize(("old", "new", "key"), [
    ("ambient_c = 23.0                    # T0, Table 5", "ambient_c = 40.0  # T0", "sma.ambient_c"),
    ("h1_w_per_m2_c = 300.0", "h1_w_per_m2_c = 210.0", "sma.h1_w_per_m2_c"),
    ("supply_voltage_v = 32.0", "supply_voltage_v = 35.2", "drive.supply_voltage_v"),
], ids=["room 40 C", "convection -30 %", "supply +10 %"])
def test_on_a_hotter_rig_the_estimate_takes_the_twins_value_and_follows_the_truth(tmp_path, old, new, key) -> None:
    got = session(tmp_path, 26.0, sim_plant=rig(tmp_path, old, new), twin=True)
    changes = got["metadata"]["safety_thermal"]["changes"]
    assert changes and key in changes[0]["values"], changes
    taken = changes[0]["applied_s"]
    assert taken < 13.0  # the twin's first 12 s window, fitted, handed over
    rig_value = float(new.split("=")[1].split("#")[0])
    assert changes[0]["values"][key] == pytest.approx(rig_value, rel=0.02)
    after = got["t"] >= taken + TAKEN_MARGIN_S
    gap = (got["estimate"] - got["truth"])[after]
    assert np.abs(gap).max() < TARGET_C, np.abs(gap).max()
    assert got["result"].events == []
    line = dict(got["result"].features["safety_thermal"].lines)["safety temperature"]
    assert key in line and "taken at" in line


# A cooler room end to end (issue 49 cut a second 26 s session, the supply 10 % low: whichever quantity
# reads looser, it is not taken, and tests/loop/test_thermal.py's
# test_only_the_stricter_end_of_a_stricter_estimate_is_taken_never_a_looser_one shows it for the supply too).
@pytest.mark.parametrize(("old", "new"), [
    ("ambient_c = 23.0                    # T0, Table 5", "ambient_c = 16.0  # T0"),
], ids=["room 16 C"])
def test_on_a_cooler_rig_nothing_is_loosened_and_the_estimate_never_reads_below_the_truth(tmp_path, old,
                                                                                         new) -> None:
    got = session(tmp_path, 26.0, sim_plant=rig(tmp_path, old, new), twin=True)
    meta = got["metadata"]
    assert meta["safety_thermal"]["changes"] == [] and meta["safety_thermal"]["values"] == meta["safety_thermal"][
        "config"]
    assert meta["twin"]["thermal"]["events"], "the twin saw the cooler rig (and the safety did not take it)"
    assert (got["estimate"] - got["truth"]).min() > -0.3
