"""What a report says: one run's identity and per-cycle table, several runs' progress; from the
command line, with its errors as one line."""

from __future__ import annotations

import pytest

from rehab_hil.cli import main
from rehab_hil.report.build import progress_rows, report_page
from rehab_hil.report.runs import ReportError, load_run


def test_a_run_report_shows_identity_and_every_cycle(tmp_path, make_run):
    page = report_page([load_run(make_run(tmp_path, "20261101T090000Z-bench7", peak_forces=(1.25, 2.5)))])
    text = page.html()
    assert "rehab_fw 9.8.7, protocol 1" in text and "abababababababab" in text  # firmware, config hash
    assert text.count("<tr><td class=\"l\">") == 2  # one table row per cycle
    assert ">1.25<" in text and ">2.5<" in text  # peak force per cycle
    assert page.n_figures == 3


def test_progress_rows_follow_the_sessions_in_time_order(tmp_path, make_run):
    runs = [load_run(make_run(tmp_path, n, rom_deg=r, peak_forces=p)) for n, r, p in
            [("20261101T0900Z-a", 20.0, (1.0, 3.0)), ("20261108T0900Z-a", 25.0, (4.0, 4.0))]]
    rows = progress_rows(runs)
    assert [r["rom_deg"] for r in rows] == [20.0, 25.0]
    assert [r["peak_force"] for r in rows] == [2.0, 4.0]  # mean of the per-cycle peaks


def test_runs_of_different_plants_are_refused(tmp_path, make_run):
    runs = [load_run(make_run(tmp_path, "a")), load_run(make_run(tmp_path, "b", plant="tcp_finger"))]
    with pytest.raises(ReportError, match="different plants"):
        report_page(runs)


def test_report_of_the_record_folder_writes_progress_html_there(tmp_path, make_run, capsys):
    for day in ("01", "08", "15"):
        make_run(tmp_path, f"202611{day}T090000Z-bench7", start=f"2026-11-{day}T09:00:00+00:00")
    assert main(["report", str(tmp_path)]) == 0
    out = capsys.readouterr().out
    assert f"wrote {tmp_path / 'progress.html'}" in out and "3 runs" in out
    assert "Progress across sessions" in (tmp_path / "progress.html").read_text()


@pytest.mark.parametrize("case", ["missing", "empty folder", "out in a missing folder"])
def test_report_mistakes_are_one_line_naming_the_path(tmp_path, make_run, capsys, case):
    run = make_run(tmp_path, "r")
    argv = {"missing": ["report", str(tmp_path / "nope")],
            "empty folder": ["report", str(run / "empty")],
            "out in a missing folder": ["report", str(run), "--out", str(tmp_path / "no" / "r.html")]}[case]
    (run / "empty").mkdir()
    assert main(argv) == 2
    err = capsys.readouterr().err.strip()
    assert "\n" not in err and err.startswith("rehab-hil report: error: ")
    assert str(tmp_path) in err


def _with_twin(run_dir, stiffness: float):
    import json

    meta_path = run_dir / "metadata.json"
    meta = json.loads(meta_path.read_text())
    meta["twin"] = {"channels": ["iris_angle_deg"]}
    meta["model_events"] = [{"kind": "model_mismatch", "t_s": 15.0, "detected_s": 15.25, "channel": "iris_angle_deg",
                             "size_counts": 5.2, "cause": "friction appearing: coulomb_friction, level_nm=0.05"}]
    meta["patient"] = {"session": {"contact_spring_damper.stiffness_nm_per_rad": {
        "value": stiffness, "ci95": 0.01, "final": stiffness, "nominal": 0.8}}}
    meta_path.write_text(json.dumps(meta))
    return run_dir


def test_a_twin_run_reports_its_model_events_and_the_patients_estimate(tmp_path, make_run):
    text = report_page([load_run(_with_twin(make_run(tmp_path, "20261101T090000Z-a"), 1.02))]).html()
    assert "friction appearing: coulomb_friction" in text and "model_mismatch" in text
    assert "contact_spring_damper.stiffness_nm_per_rad" in text and ">1.02<" in text


def test_progress_follows_the_interaction_stiffness_across_sessions(tmp_path, make_run):
    runs = [load_run(_with_twin(make_run(tmp_path, n), k)) for n, k in
            [("20261101T0900Z-a", 1.0), ("20261108T0900Z-a", 1.6)]]
    assert [r["stiffness"] for r in progress_rows(runs)] == [1.0, 1.6]
    assert "no session ran the live twin" not in report_page(runs).html()
