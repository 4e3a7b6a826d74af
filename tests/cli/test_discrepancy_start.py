"""``rehab-hil discrepancy --start auto|rest|estimate`` with several records (issue 38 item 5): the option
holds for every record, each judged on its own data. A servo record from standstill and one cut in
mid-motion (open-loop torque steps, angle only), fitted together from the CLI."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from rehab_hil.cli import main
from rehab_hil.discrepancy.synthetic import step_records
from rehab_hil.interchange import Recording, write_csv
from rehab_hil.loading import load_config
from rehab_hil.plants import get_plant
from rehab_hil.testing import CONFIGS

SERVO = CONFIGS / "servo_axis_nominal.toml"
CUT_S = 3.0  # the second record begins here: 1 s into a torque step, turning


@pytest.fixture(scope="module")
def records(tmp_path_factory: pytest.TempPathFactory) -> list[Path]:
    cfg = load_config(SERVO)
    rest, moving = step_records(get_plant(cfg.plant), cfg, {"coulomb_friction": {"level_nm": 0.02}},
                                directions=(1, -1), duration_s=8.0, seed=3)
    k = round(CUT_S / float(moving.t[1] - moving.t[0]))
    cut = Recording(moving.t[k:] - moving.t[k], {c: v[k:] for c, v in moving.signals.items()})
    d = tmp_path_factory.mktemp("start")
    return [write_csv(d / name, r.t, {c: v for c, v in r.signals.items() if c != "velocity_rad_s"})  # not logged
            for name, r in (("from_rest.csv", rest), ("mid_motion.csv", cut))]


def _starts(tmp_path: Path, records: list[Path], start: str) -> tuple[list[dict], str]:
    out = tmp_path / start
    assert main(["discrepancy", "--config", str(SERVO), "--data", str(records[0]), "--data", str(records[1]),
                 "--start", start, "--max-effects", "1", "--out", str(out)]) == 0
    rep = json.loads((out / "report.json").read_text())
    return [g["start"] for g in rep["gaps"]["records"]], (out / "report.md").read_text()


def _velocity(start: dict) -> float | None:
    return next((v for k, v in start["estimated"].items() if "velocity" in k), None)


def test_start_rest_keeps_every_record_at_rest_even_one_cut_in_motion(tmp_path, records, capsys):
    starts, md = _starts(tmp_path, records, "rest")
    assert [s["at_rest"] for s in starts] == ["option", "option"]
    assert all(s["estimated"] == {} for s in starts)
    printed = {ln.split(":")[0].strip(): ln for ln in capsys.readouterr().out.splitlines() if "start of" in ln}
    for name in ("from_rest.csv", "mid_motion.csv"):
        assert "starts at rest, said so (--start rest)" in printed[f"start of {name}"]
    assert "said so (--start rest)" in md


def test_start_auto_keeps_the_record_from_standstill_at_rest_and_estimates_the_one_in_motion(tmp_path, records):
    (rest, moving), _ = _starts(tmp_path, records, "auto")
    # found at rest from its data, or its fitted start velocity too small to move the angle beyond its
    # noise (0.01 deg) in the first 50 ms
    v = _velocity(rest)
    assert rest["at_rest"] == "data" or (v is not None and abs(v) * 0.05 < 4 * 1.75e-4)
    assert moving["at_rest"] == "" and abs(_velocity(moving)) > 1.0  # rad/s: 1 s into a step


def test_start_estimate_estimates_every_record_even_one_from_standstill(tmp_path, records):
    (rest, moving), _ = _starts(tmp_path, records, "estimate")
    assert rest["at_rest"] == "" and _velocity(rest) is not None
    assert moving["at_rest"] == "" and abs(_velocity(moving)) > 1.0
