"""The command end to end: report files, the documented JSON keys, a loadable augmented.toml."""

from __future__ import annotations

import json

import pytest

from rehab_hil.cli import main
from rehab_hil.discrepancy.synthetic import hidden_effect_recording
from rehab_hil.interchange import write_csv
from rehab_hil.loading import load_config

from .conftest import FE_CONFIG


@pytest.mark.slow
def test_discrepancy_command_writes_report_and_an_augmented_config_that_loads(fe, tmp_path, capsys):
    spec, cfg = fe
    rec = hidden_effect_recording(spec, cfg, {"viscous_friction": {"damping_nm_s_per_rad": 0.03}},
                                  duration_s=8.0, seed=5)
    data = write_csv(tmp_path / "measured.csv", rec.t, rec.signals)
    out = tmp_path / "report"
    code = main(["discrepancy", "--config", str(FE_CONFIG), "--data", str(data), "--out", str(out),
                 "--max-effects", "1"])
    assert code == 0
    assert "missing effect found: viscous_friction" in capsys.readouterr().out
    for name in ("report.json", "report.md", "overlay.png", "residual.png", "regions.png", "augmented.toml"):
        assert (out / name).stat().st_size > 0, name
    rep = json.loads((out / "report.json").read_text())
    assert rep["schema"] == "rehab-hil/discrepancy-report/1"
    assert rep["conclusion"] == "missing effect found: viscous_friction"
    assert set(rep["metrics"]) == {"nominal", "augmented", "nominal_holdout", "augmented_holdout"}
    assert rep["chosen"][0]["params"]["damping_nm_s_per_rad"] == pytest.approx(0.03, abs=0.004)
    assert rep["chosen"][0]["stderr"]["damping_nm_s_per_rad"] > 0
    assert rep["rounds"][0]["candidates"][0]["effect"] == "viscous_friction"
    assert {g["region"] for g in rep["localisation"]["regions"]} >= {"reversal", "rest", "fast_motion"}
    assert rep["gap_reduction_pct"]["iris_angle_deg"] > 50
    aug = load_config(out / "augmented.toml")
    assert [(e.name, round(e.params["damping_nm_s_per_rad"], 3)) for e in aug.effects] == [
        ("viscous_friction", round(rep["chosen"][0]["params"]["damping_nm_s_per_rad"], 3))]


def test_simulate_refuses_an_effect_that_does_not_apply(capsys):
    code = main(["simulate", "--config", str(FE_CONFIG), "--scenario", "step", "--effect", "sma_hysteresis:width_c=5"])
    assert code == 2
    assert "does not apply to plant 'finger_extensor'" in capsys.readouterr().err


@pytest.mark.slow
def test_simulate_with_a_hidden_effect_changes_the_recording(tmp_path):
    from rehab_hil.interchange import read_csv

    base, fx = tmp_path / "base.csv", tmp_path / "fx.csv"
    args = ["simulate", "--config", str(FE_CONFIG), "--scenario", "step", "--duration", "0.5"]
    assert main([*args, "--out", str(base)]) == 0
    assert main([*args, "--out", str(fx), "--effect", "time_delay:delay_s=0.02"]) == 0
    a, b = read_csv(base), read_csv(fx)
    assert abs(a["iris_angle_deg"][100] - b["iris_angle_deg"][100]) > 1.0  # the delayed drive lags
    assert load_config(FE_CONFIG).plant == "finger_extensor"
