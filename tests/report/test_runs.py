"""Reading run directories for the report: what a typed path names, the per-cycle peak force from
the record, a run cut short."""

from __future__ import annotations

import numpy as np
import pytest

from rehab_hil.report.runs import ReportError, find_runs, load_run


def test_find_runs_takes_a_run_dir_its_csv_or_every_run_in_the_record_folder(tmp_path, make_run):
    a = make_run(tmp_path, "20261101T090000Z-bench7")
    b = make_run(tmp_path, "20261102T090000Z-bench7")
    (tmp_path / "notes").mkdir()  # not a run: left out
    assert find_runs(a) == [a]
    assert find_runs(a / "run.csv") == [a]
    assert find_runs(tmp_path) == [a, b]  # oldest first


def test_a_simulated_csv_in_the_record_folder_is_not_taken_for_a_run(tmp_path, make_run):
    """``simulate --out out/run.csv`` and ``make run`` (``--record out/``) share the README's out/."""
    a = make_run(tmp_path, "20261101T090000Z-bench7")
    (tmp_path / "run.csv").write_text("time_s,x_deg\n0,1\n")
    assert find_runs(tmp_path) == [a]
    with pytest.raises(ReportError, match=r"run\.csv: not in a run directory \(no metadata\.json beside it"):
        find_runs(tmp_path / "run.csv")


def test_find_runs_names_a_missing_path_and_a_folder_without_runs(tmp_path):
    with pytest.raises(ReportError, match="no such file or directory"):
        find_runs(tmp_path / "nope")
    with pytest.raises(ReportError, match=f"{tmp_path}: no run here"):
        find_runs(tmp_path)
    (tmp_path / "x.txt").write_text("hi")
    with pytest.raises(ReportError, match=r"x\.txt: not a run directory"):
        find_runs(tmp_path / "x.txt")


def test_load_run_adds_each_cycles_peak_force_from_the_record(tmp_path, make_run):
    run = load_run(make_run(tmp_path, "r", peak_forces=(1.5, 2.5, 0.75)))
    assert [c["peak_force"] for c in run.cycles] == [1.5, 2.5, 0.75]
    assert run.period_s == pytest.approx(4.0)
    assert run.angle_name == "theta_mcp_deg" and run.sensor_name == "contact_force_n"
    assert run.temperature is not None and set(run.duty) == {"applied_duty0_ratio"}  # duty1 is all zero
    assert np.all(np.diff(run.t) > 0)


def test_a_run_killed_mid_line_is_read_to_its_last_complete_sample_with_a_note(tmp_path, make_run):
    d = make_run(tmp_path, "r", ended=False)
    text = (d / "run.csv").read_text()
    (d / "run.csv").write_text(text + "99.5,0.1,")  # the writer killed mid-line
    run = load_run(d)
    assert run.t[-1] < 99.0 and run.cycles == []
    assert any("no end record" in n for n in run.notes)


def test_a_run_without_metadata_is_named(tmp_path):
    d = tmp_path / "r"
    d.mkdir()
    (d / "run.csv").write_text("time_s,x\n0,1\n")
    with pytest.raises(ReportError, match=r"metadata.json: no metadata file"):
        load_run(d)
