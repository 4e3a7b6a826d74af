"""``rehab-hil discrepancy --data A --data B --validate C``: one parameter set over several records,
the gap per record and overall in one measure (issue 38 item 1), from the CLI."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from rehab_hil.cli import main
from rehab_hil.discrepancy.records import GAP_MEASURE
from rehab_hil.discrepancy.synthetic import step_records
from rehab_hil.interchange import write_csv
from rehab_hil.loading import load_config
from rehab_hil.plants import get_plant
from rehab_hil.testing import CONFIGS

SERVO = CONFIGS / "servo_axis_nominal.toml"


def test_two_records_of_opposite_directions_and_a_validation_record_from_the_cli(
        tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    cfg = load_config(SERVO)
    recs = step_records(get_plant(cfg.plant), cfg,
                        {"coulomb_friction_directional": {"level_pos_nm": 0.03, "level_neg_nm": 0.012}},
                        directions=(1, -1, 1), duration_s=8.0, seed=5)
    paths = [write_csv(tmp_path / f"servo_{i}.csv", r.t, r.signals) for i, r in enumerate(recs)]
    out = tmp_path / "report"
    rc = main(["discrepancy", "--config", str(SERVO), "--data", str(paths[0]), "--data", str(paths[1]),
               "--validate", str(paths[2]), "--out", str(out)])
    assert rc == 0
    printed = capsys.readouterr().out
    assert "friction 0.03 N m turning +, 0.012 N m turning -" in printed
    assert GAP_MEASURE in printed
    for name in ("servo_0.csv", "servo_1.csv", "servo_2.csv", "overall"):
        assert name in printed
    rep = json.loads((out / "report.json").read_text())
    assert [g["data"] for g in rep["gaps"]["records"]] == [str(paths[0]), str(paths[1])]
    assert [g["data"] for g in rep["gaps"]["validation"]] == [str(paths[2])]
    for g in rep["gaps"]["records"] + rep["gaps"]["validation"]:
        assert g["augmented"]["angle_deg"]["rmse"] < 0.01 * g["nominal"]["angle_deg"]["rmse"]
    assert load_config(out / "augmented.toml").effects[0].name == "coulomb_friction_directional"


def test_discrepancy_before_and_replay_of_the_nominal_model_give_the_same_figure(
        tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    # issue 41 item 6: on the same data and config `discrepancy` printed "before 2.773 deg" (multiple
    # shooting) and `replay` 16.75 (open loop from rest); both now give the whole-record replay from the
    # start state estimated from the record, never re-anchored
    emps = Path(__file__).resolve().parents[1] / "data" / "emps" / "estimation_6s_500hz.csv"
    config = str(CONFIGS / "emps_nominal.toml")
    assert main(["replay", "--config", config, "--data", str(emps)]) == 0
    line = next(ln for ln in capsys.readouterr().out.splitlines() if ln.strip().startswith("position_m"))
    replayed = float(line.split("RMSE")[1].split()[0])
    assert main(["discrepancy", "--config", config, "--data", str(emps), "--out", str(tmp_path / "r")]) == 0
    line = next(ln for ln in capsys.readouterr().out.splitlines() if "estimation" in ln and "position_m" in ln)
    before = float(line.split("position_m")[1].split("->")[0])
    assert before == pytest.approx(replayed, rel=1e-3)
