"""``rehab-hil run --controller assist_as_needed --sim-patient`` on each shipped plant, in process
(lockstep): the capable patient's session records the therapist's measures per cycle and keeps the
learned assistance for the patient's next session; a store that cannot be used is one warning line."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from rehab_hil.cli import main
from rehab_hil.controllers import Reference
from rehab_hil.loading import load_config

ROOT = Path(__file__).resolve().parents[2]
CAPABLE = ROOT / "profiles" / "sim" / "capable.toml"

pytestmark = pytest.mark.slow


def run(config: Path, cycles: int, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> tuple[int, str]:
    ref = Reference.session(load_config(config))
    code = main(["run", "--config", str(config), "--device", "inprocess", "--controller", "assist_as_needed",
                 "--sim-patient", str(CAPABLE), "--duration", f"{ref.first_open_s + cycles * ref.period_s + 0.5}",
                 "--record", str(tmp_path / "runs"), "--assistance-store", str(tmp_path / "store"), "--no-display"])
    return code, capsys.readouterr().out


@pytest.mark.parametrize(("plant", "cycles"), [("finger_extensor", 2), ("sma_exoskeleton", 2), ("tcp_finger", 1)])
def test_each_plant_runs_an_assist_as_needed_session_with_the_capable_patient(plant, cycles, tmp_path, capsys):
    code, out = run(ROOT / "configs" / f"{plant}.toml", cycles, tmp_path, capsys)
    assert code == 0, out
    (run_dir,) = (tmp_path / "runs").iterdir()
    meta = json.loads((run_dir / "metadata.json").read_text())
    cycles_done = meta["session_cycles"]
    assert len(cycles_done) == cycles and meta["safety_events"] == []
    assert all(c["success_assisted"] == 1.0 and c["assistance_ratio"] >= 0.0 for c in cycles_done)
    kept = meta["assistance_store"]
    assert "assistance kept" in out  # the summary's rows, with what a therapist reads first
    assert "per cycle: success" in out and f"{cycles_done[0]['assistance_ratio']:.2f} ->" in out
    a0 = load_config(ROOT / "configs" / f"{plant}.toml").controllers["assist_as_needed"].initial_assistance
    assert Path(kept["store"]).exists() and kept["end"]["open"] < kept["start"]["open"] == a0


def test_a_corrupt_store_is_one_warning_line_and_the_session_runs_from_the_default(tmp_path, capsys):
    config = ROOT / "configs" / "finger_extensor.toml"
    code, _ = run(config, 1, tmp_path, capsys)
    (store,) = (tmp_path / "store").rglob("*.json")
    store.write_text("not json")
    code, out = run(config, 1, tmp_path, capsys)
    assert code == 0, out
    warnings = [line for line in out.splitlines() if line.startswith("warning: assistance store")]
    assert len(warnings) == 1 and str(store) in warnings[0] and "unreadable" in warnings[0]
    assert json.loads(store.read_text())["sessions"] == 1  # the default start, saved readable again
