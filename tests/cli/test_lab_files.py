"""A lab's own logger files straight into ``rehab-hil discrepancy`` and ``replay`` (issue 38 item 4): a
servo commanded in torque, logged as a CSV whose time column is ``time`` and as a MATLAB v7.3 file
holding one matrix, read through the config's ``[import]``; its measured velocity is a compared
channel. The record is simulated here with a hidden Coulomb friction of 0.02 N m."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from rehab_hil.cli import main
from rehab_hil.loading import load_config
from rehab_hil.plants import get_plant, run_scenario
from rehab_hil.plants.experiments import Scenario
from rehab_hil.testing import servo_axis_config

ROOT = Path(__file__).resolve().parents[2]
IMPORT = """[import]
time = "{time}"
[import.signals.drive_torque_nm]
variable = "{tau}"
unit = "N m"
[import.signals.angle_deg]
variable = "{theta}"
unit = "rad"
[import.signals.velocity_rad_s]
variable = "{omega}"
unit = "rad/s"
"""
CSV_NAMES = {"time": "time", "tau": "tau", "theta": "theta", "omega": "omega"}
MAT_NAMES = {"time": "data(:,1)", "tau": "data(:,2)", "theta": "data(:,4)", "omega": "data(:,5)"}


def _config(tmp_path: Path, names: dict[str, str], extra: str = "") -> Path:
    f = tmp_path / f"servo_{len(list(tmp_path.glob('servo_*')))}.toml"
    return servo_axis_config(f, load="stick_velocity = 0.01\nstick_damping = 0.05",
                             extra=IMPORT.format(**names) + extra)


def _record(tmp_path: Path, seconds: float = 8.0) -> np.ndarray:
    """time, torque, an unused column, angle [rad], velocity [rad/s] of the servo with a hidden Coulomb
    friction, under torque steps of either sign; with encoder and tachometer noise."""
    hidden = load_config(_config(tmp_path, CSV_NAMES, '[[effects]]\nname = "coulomb_friction"\n'
                                                      'params = { level_nm = 0.02 }\n'))
    n = int(seconds * 1000)
    t = np.arange(n) * 1e-3
    tau = np.where((t % 4) < 2, 0.06, -0.05) * (t > 0.5)
    res = run_scenario(get_plant("motor_axis"), hidden, Scenario("steps", n, inputs={"drive_torque_nm": tau}))
    rng = np.random.default_rng(3)
    return np.column_stack([t, tau, np.zeros(n), np.radians(res["angle_deg"]) + rng.normal(0, 1e-4, n),
                            res["velocity_rad_s"] + rng.normal(0, 0.05, n)])


def test_a_logger_csv_with_a_time_column_is_analysed_through_the_config_mapping(
        tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    data = _record(tmp_path)
    log = tmp_path / "logger.csv"
    np.savetxt(log, data[:, [0, 1, 3, 4]], delimiter=",", header="time,tau,theta,omega", comments="", fmt="%.6g")
    cfg = _config(tmp_path, CSV_NAMES)
    assert main(["replay", "--config", str(cfg), "--data", str(log)]) == 0
    assert "velocity_rad_s" in capsys.readouterr().out
    out = tmp_path / "rep"
    assert main(["discrepancy", "--config", str(cfg), "--data", str(log), "--out", str(out),
                 "--max-effects", "1"]) == 0
    rep = json.loads((out / "report.json").read_text())
    assert set(rep["channels"]) == {"angle_deg", "velocity_rad_s"}
    assert [c["effect"] for c in rep["chosen"]] == ["coulomb_friction"]
    assert rep["chosen"][0]["params"]["level_nm"] == pytest.approx(0.02, rel=0.1)


def test_a_matlab_v73_matrix_is_replayed_column_by_column(tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    import h5py

    data = _record(tmp_path, 4.0)
    mat = tmp_path / "servo73.mat"
    with h5py.File(mat, "w", userblock_size=512) as f:  # MATLAB's layout: column-major, a text header
        f.create_dataset("data", data=data.T).attrs["MATLAB_class"] = np.bytes_("double")
    with mat.open("r+b") as fh:
        fh.write(b"MATLAB 7.3 MAT-file, Platform: GLNXA64, HDF5 schema 1.00 .".ljust(116) + b"\x00" * 8 + b"\x00\x02IM")
    assert main(["replay", "--config", str(_config(tmp_path, MAT_NAMES)), "--data", str(mat)]) == 0
    printed = capsys.readouterr().out
    assert "4000 samples" in printed and "velocity_rad_s" in printed


def test_a_file_that_is_not_a_mat_file_is_one_line(tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    fake = tmp_path / "run.mat"
    fake.write_text("time,tau\n0,1\n")
    assert main(["replay", "--config", str(_config(tmp_path, MAT_NAMES)), "--data", str(fake)]) == 2
    err = capsys.readouterr().err.strip()
    assert "run.mat: not a MAT file" in err and len(err.splitlines()) == 1
