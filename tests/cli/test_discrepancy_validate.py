"""``rehab-hil discrepancy --validate``: fit on one real EMPS record, score on another, from the CLI
(6 s excerpts in tests/data/emps, README there)."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from rehab_hil.cli import main
from rehab_hil.loading import load_config

ROOT = Path(__file__).resolve().parents[2]
DATA = ROOT / "tests" / "data" / "emps"


def test_validate_scores_the_augmented_model_on_the_pulse_run_and_the_report_says_so(
        tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    out = tmp_path / "report"
    rc = main(["discrepancy", "--config", str(ROOT / "configs" / "emps_nominal.toml"),
               "--data", str(DATA / "estimation_6s_500hz.csv"), "--validate", str(DATA / "validation_6s_500hz.csv"),
               "--out", str(out)])
    assert rc == 0
    printed = capsys.readouterr().out
    assert "validation on" in printed and "closed loop" in printed
    assert "(cut by " in printed and "% cut)" not in printed  # a change worded as what it is
    rep = json.loads((out / "report.json").read_text())
    assert rep["validation"]["error_cut_pct"]["drive_input_v"] >= 60.0
    assert rep["validation"]["error_change"]["drive_input_v"].startswith("cut by ")
    judged = rep["held_out_judgement"]  # the findings were judged on the validation record, which kept them
    assert judged["on"] == "the validation records" and judged["rejected"] == []
    assert judged["final"]["rmse"]["drive_input_v"] < judged["given"]["rmse"]["drive_input_v"]
    assert rep["replay"]["loop"].startswith("closed loop")
    coulomb = next(c for c in rep["chosen"] if c["effect"] == "coulomb_friction")  # a linear axis: newtons
    assert coulomb["units"] == {"level_nm": "N"} and "Karnopp" in coulomb["seed"] and "seed 00" not in coulomb["seed"]
    assert "level = " in (out / "report.md").read_text() and " N ± " in (out / "report.md").read_text()
    aug = load_config(out / "augmented.toml")  # Coulomb friction of 20 N: within the axis's scaled bounds
    assert {e.name for e in aug.effects} == {"coulomb_friction", "constant_load"}
    assert aug.import_ is not None and aug.recorded_controller is not None


def test_a_validation_record_that_is_missing_is_one_line_before_any_fit(tmp_path: Path,
                                                                         capsys: pytest.CaptureFixture) -> None:
    rc = main(["discrepancy", "--config", str(ROOT / "configs" / "emps_nominal.toml"),
               "--data", str(DATA / "estimation_6s_500hz.csv"), "--validate", str(tmp_path / "nope.mat"),
               "--out", str(tmp_path / "r")])
    assert rc == 2
    err = capsys.readouterr().err.strip()
    assert "\n" not in err and "nope.mat" in err and not (tmp_path / "r" / "report.json").exists()
