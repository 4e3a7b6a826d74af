"""Rig recordings read as the model sees them, and what happens to bad ones: another plant's run,
a missing channel, a run killed mid-write (CSV or MCAP cut short), an empty run directory."""

from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np
import pytest

from rehab_hil.cli import main
from rehab_hil.interchange import CsvError
from rehab_hil.loading import load_config
from rehab_hil.plants import get_plant
from rehab_hil.rig_recording import load_recording, read_recording

ROOT = Path(__file__).resolve().parents[1]
FE, SMA = ROOT / "configs" / "finger_extensor.toml", ROOT / "configs" / "sma_exoskeleton.toml"

# one xdist worker runs the module, so the recorded session is made once (under make test's two
# workers each made its own: 0.9 s of set-up each)
pytestmark = pytest.mark.xdist_group("rig_recording_fe_run")


@pytest.fixture(scope="module")
def fe_run(tmp_path_factory) -> Path:
    """A 3 s Finger Extensor session on the in-process rig, recorded."""
    root = tmp_path_factory.mktemp("runs")
    assert main(["run", "--config", str(FE), "--device", "inprocess", "--duration", "3", "--record", str(root),
                 "--no-display"]) == 0
    (run,) = root.iterdir()
    return run


def _fe():
    cfg = load_config(FE)
    return get_plant(cfg.plant), cfg


def test_a_run_directory_reads_as_the_models_signals(fe_run):
    plant, cfg = _fe()
    loaded = load_recording(fe_run, plant, cfg)
    assert loaded.source.name == "run.csv" and loaded.notes == [] and loaded.metadata["plant"] == "finger_extensor"
    assert set(plant.inputs) <= set(loaded.recording.signals) and "iris_angle_deg" in loaded.recording.signals


def test_the_mcap_holds_the_same_samples_as_the_csv(fe_run):
    csv, mcap = read_recording(fe_run / "run.csv").recording, read_recording(fe_run / "run.mcap").recording
    np.testing.assert_allclose(mcap.t, csv.t)
    for name in ("iris_angle_deg", "motor_voltage_v", "patient_torque_nm"):
        np.testing.assert_allclose(mcap[name], csv[name], rtol=1e-9, atol=1e-9)


def test_an_unrecorded_constant_input_is_taken_from_the_config_and_said(tmp_path):
    plant, cfg = get_plant("sma_exoskeleton"), load_config(SMA)
    path = tmp_path / "sma.csv"
    path.write_text("time_s,pwm_duty,theta_mcp_deg\n0,0,0\n0.001,0.5,0\n")
    loaded = load_recording(path, plant, cfg)
    assert np.all(loaded.recording["supply_voltage_v"] == cfg.drive.supply_voltage_v)
    assert loaded.notes == ["supply_voltage_v is not recorded: taken from the config (32)"]


def test_a_run_of_another_plant_is_refused_naming_the_metadata_file(fe_run):
    plant, cfg = get_plant("sma_exoskeleton"), load_config(SMA)
    with pytest.raises(CsvError, match=r"metadata.json: a 'finger_extensor' recording; the config is a "
                                       r"'sma_exoskeleton' plant"):
        load_recording(fe_run, plant, cfg)


def test_an_empty_run_directory_is_refused(tmp_path, capsys):
    empty = tmp_path / "20261123T000000Z-bench1"
    empty.mkdir()
    assert main(["discrepancy", "--config", str(FE), "--data", str(empty), "--out", str(tmp_path / "r")]) == 2
    assert "no run.csv or run.mcap here" in capsys.readouterr().err


def test_a_recording_missing_a_required_channel_is_refused_in_one_line(fe_run, tmp_path, capsys):
    text = (fe_run / "run.csv").read_text().splitlines()
    cols = text[0].split(",")
    keep = [i for i, c in enumerate(cols) if c != "motor_voltage_v"]
    path = tmp_path / "no_voltage.csv"
    path.write_text("\n".join(",".join(row.split(",")[i] for i in keep) for row in text) + "\n")
    assert main(["discrepancy", "--config", str(FE), "--data", str(path), "--out", str(tmp_path / "r")]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "missing input columns ['motor_voltage_v']" in err and str(path) in err


def test_a_killed_runs_csv_is_read_up_to_its_last_complete_sample(fe_run, tmp_path):
    run = tmp_path / "killed"
    shutil.copytree(fe_run, run)
    raw = (run / "run.csv").read_bytes()
    (run / "run.csv").write_bytes(raw[: len(raw) - 40])  # the last line cut mid-number
    plant, cfg = _fe()
    loaded = load_recording(run, plant, cfg)
    full = read_recording(fe_run).recording
    assert loaded.recording.t.size == full.t.size - 1
    assert "cut short" in loaded.notes[0]


def test_a_killed_runs_mcap_without_footer_is_read_up_to_its_last_complete_sample(fe_run, tmp_path):
    raw = (fe_run / "run.mcap").read_bytes()
    path = tmp_path / "killed.mcap"
    path.write_bytes(raw[: len(raw) // 2])  # no summary, no footer, a message cut in half
    loaded = read_recording(path)
    assert 0 < loaded.recording.t.size < read_recording(fe_run / "run.csv").recording.t.size
    assert "no MCAP footer" in loaded.notes[0]


def test_a_second_recording_never_overwrites_the_first(fe_run, tmp_path):
    root = fe_run.parent
    before = {p.name: (p / "run.csv").stat().st_mtime_ns for p in root.iterdir()}
    assert main(["run", "--config", str(FE), "--device", "inprocess", "--duration", "0.5", "--record", str(root),
                 "--no-display"]) == 0
    after = {p.name: (p / "run.csv").stat().st_mtime_ns for p in root.iterdir()}
    assert len(after) == len(before) + 1 and all(after[k] == v for k, v in before.items())


def test_the_mcap_carries_the_runs_metadata_records(fe_run):
    import json

    from mcap.reader import make_reader

    with (fe_run / "run.mcap").open("rb") as fh:
        meta = {m.name: m.metadata for m in make_reader(fh).iter_metadata()}
    assert meta["rehab_hil.session"]["plant"] == "finger_extensor"
    assert json.loads(meta["rehab_hil.session"]["calibration"])["adc"][0]["signal"] == "patient_torque_nm"
    summary = meta["rehab_hil.summary"]
    assert json.loads(summary["safety_events"]) == [] and float(summary["duration_s"]) > 2.9
