"""``rehab-hil simulate --power-w`` and ``rehab-hil identify`` / ``sensitivity`` on the TCP finger."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from rehab_hil.cli import main
from rehab_hil.interchange import read_csv, write_csv

ROOT = Path(__file__).resolve().parents[2]
CFG = ROOT / "configs" / "tcp_finger.toml"


@pytest.fixture(scope="module")
def run_csv(tmp_path_factory):
    out = tmp_path_factory.mktemp("tcp") / "run.csv"
    assert main(["simulate", "--config", str(CFG), "--scenario", "pulse", "--power-w", "40",
                 "--duration", "15", "--out", str(out)]) == 0
    return out


def test_simulate_pulse_with_power_writes_the_tcp_finger_columns(run_csv):
    rec = read_csv(run_csv)
    rec.require(["power_w", "tcp_temperature_c", "tcp_force_n", "theta_mcp_deg", "theta_pip_deg", "theta_dip_deg"])
    assert rec["power_w"].max() == 40.0 and rec["power_w"][-1] == 0.0
    assert rec["tcp_force_n"].max() == pytest.approx(2.06, rel=0.01)


def test_identify_prints_a_fit_table_and_recovers_tf1(run_csv, capsys):
    assert main(["identify", "--data", str(run_csv), "--input", "power_w", "--output", "tcp_temperature_c",
                 "--orders", "1-2"]) == 0
    text = capsys.readouterr().out
    lines = [ln for ln in text.splitlines() if ln.strip()[:1].isdigit()]
    assert len(lines) == 5  # (1,0) (1,1) (2,0) (2,1) (2,2)
    best = next(ln for ln in lines if "recommended" in ln)
    assert best.split()[0] == "2"
    assert float(best.split()[2]) > 99.0  # fit % of the recommended model on noiseless data


def test_identify_refuses_a_constant_input_in_one_line(tmp_path, capsys):
    t = np.arange(1000) * 0.01
    path = write_csv(tmp_path / "flat.csv", t, {"power_w": np.full_like(t, 34.0), "tcp_temperature_c": t})
    assert main(["identify", "--data", str(path), "--input", "power_w", "--output", "tcp_temperature_c"]) == 2
    err = capsys.readouterr().err
    assert "input is constant" in err and str(path) in err and len(err.strip().splitlines()) == 1


def test_identify_refuses_a_missing_column_and_bad_orders(run_csv, capsys):
    assert main(["identify", "--data", str(run_csv), "--input", "current_a", "--output", "tcp_force_n"]) == 2
    assert "current_a" in capsys.readouterr().err
    assert main(["identify", "--data", str(run_csv), "--input", "power_w", "--output", "tcp_force_n",
                 "--orders", "3-1"]) == 2
    assert "--orders" in capsys.readouterr().err


def test_power_is_refused_by_a_scenario_without_it(capsys):
    assert main(["simulate", "--config", str(CFG), "--scenario", "fis", "--power-w", "34"]) == 2
    assert "takes no --power-w" in capsys.readouterr().err


def test_sensitivity_prints_one_row_per_variation(capsys):
    assert main(["sensitivity", "--config", str(CFG)]) == 0
    text = capsys.readouterr().out
    for name in ("nominal", "mass", "inertia", "damping", "K"):
        assert f" {name} " in text
    assert len([ln for ln in text.splitlines() if "|" in ln]) == 1 + 1 + 8  # header, nominal, 4 x 2
