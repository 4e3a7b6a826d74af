"""The ``rehab-hil simulate`` command: writes the CSV, prints metrics, and fails cleanly."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

from rehab_hil.cli import main
from rehab_hil.interchange import read_csv

ROOT = Path(__file__).resolve().parents[2]
CFG = ROOT / "configs" / "finger_extensor.toml"


def test_simulate_writes_the_interchange_csv_and_prints_metrics(tmp_path, capsys):
    out = tmp_path / "run.csv"
    assert main(["simulate", "--config", str(CFG), "--scenario", "step", "--duration", "1", "--out", str(out)]) == 0
    text = capsys.readouterr().out
    assert "overshoot" in text and "rise_time_s" in text
    rec = read_csv(out)
    assert len(rec.t) == 1000
    rec.require(["motor_voltage_v", "patient_torque_nm", "iris_angle_deg", "motor_current_a"])
    assert rec["iris_angle_deg"][-1] > 50.0


def test_a_bad_config_prints_one_line_naming_file_and_key(tmp_path):
    bad = tmp_path / "bad.toml"
    bad.write_text(CFG.read_text().replace("resistance_ohm = 3.0", "resistance_ohm = -3.0"))
    proc = subprocess.run(
        [sys.executable, "-m", "rehab_hil.cli", "simulate", "--config", str(bad), "--scenario", "step"],
        capture_output=True, text=True, timeout=120,
    )
    assert proc.returncode == 2
    assert "Traceback" not in proc.stderr
    assert str(bad) in proc.stderr and "motor.resistance_ohm" in proc.stderr


def test_an_unknown_scenario_is_refused(capsys):
    assert main(["simulate", "--config", str(CFG), "--scenario", "moonwalk"]) == 2
    assert "no scenario 'moonwalk'" in capsys.readouterr().err
