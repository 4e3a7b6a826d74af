"""``rehab-hil discrepancy`` writes report.html beside report.md: the same kind of page, drawn in
Chromium; a bad --out is refused before the fit (nothing computed is lost)."""

from __future__ import annotations

import pytest

from rehab_hil.cli import main
from rehab_hil.discrepancy.synthetic import hidden_effect_recording
from rehab_hil.interchange import write_csv
from rehab_hil.loading import load_config
from rehab_hil.plants import get_plant
from rehab_hil.report.browser import check_page, find_chromium
from rehab_hil.testing import CONFIGS

FE_CONFIG = CONFIGS / "finger_extensor.toml"


@pytest.fixture(scope="module")
def measured(tmp_path_factory):
    cfg = load_config(FE_CONFIG)
    rec = hidden_effect_recording(get_plant(cfg.plant), cfg, {"viscous_friction": {"damping_nm_s_per_rad": 0.03}},
                                  duration_s=3.0, seed=5)
    return write_csv(tmp_path_factory.mktemp("data") / "measured.csv", rec.t, rec.signals)


@pytest.mark.slow
def test_discrepancy_writes_an_html_report_beside_the_markdown(measured, tmp_path, capsys):
    out = tmp_path / "report"
    assert main(["discrepancy", "--config", str(FE_CONFIG), "--data", str(measured), "--out", str(out),
                 "--max-effects", "1"]) == 0
    page = (out / "report.html").read_text()
    assert (out / "report.md").is_file() and "viscous_friction" in page and "iris_angle_deg" in page
    # everything report.md holds (issue 41 item 4): ranking, joint identification, replay mode, start state, units
    for held in ("Round 1: candidates", "Joint identification", "Mode: ", "Start state: ", "noise floor",
                 "iris_angle_deg [deg]", "N m s/rad"):
        assert held in page, held
    if find_chromium() is None:
        pytest.skip("no chromium: scripts/install_browser.sh installs it (make test does, as root)")
    c = check_page(out / "report.html")
    assert c.state == "drawn" and c.errors == [] and c.plots == c.drawn == 2


def test_discrepancy_refuses_an_out_that_is_a_file_before_fitting(measured, tmp_path, capsys):
    out = tmp_path / "report.md"
    out.write_text("mine")
    assert main(["discrepancy", "--config", str(FE_CONFIG), "--data", str(measured), "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert err.strip() == f"rehab-hil discrepancy: error: --out {out}: a file, not a folder (the report is " \
                          "several files)"
    assert out.read_text() == "mine"
