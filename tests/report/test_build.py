"""What a report says: one run's identity and per-cycle table, several runs' progress; from the
command line, with its errors as one line."""

from __future__ import annotations

import json

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


def test_a_tripped_runs_report_says_when_and_why_it_stopped_not_the_time_asked(tmp_path, make_run):
    trip = {"t_s": 11.02, "reason": "watchdog", "detail": "no command for 120 ms"}
    text = report_page([load_run(make_run(tmp_path, "r", events=[trip], requested_s=30.0))]).html()
    assert "11.02 s of the 30 s asked" in text and "30.00 s" not in text
    assert "safety trip: watchdog at 11.02 s (no command for 120 ms)" in text
    assert 'class="note">This session ran 11.02 s of the 30 s asked' in text  # said before the plots


def test_a_link_loss_says_whose_stall_it_was_and_that_the_pwm_off_is_unconfirmed(tmp_path, make_run):
    trip = {"t_s": 0.68, "reason": "link_loss", "detail": "no sample for 200 ms",
            "cause": "not a host stall: the device sent nothing while it could run"}
    run = make_run(tmp_path, "r", events=[trip], requested_s=30.0)
    meta = json.loads((run / "metadata.json").read_text())
    meta |= {"pwm_off_at_end": None, "pwm_unconfirmed": "no sample came after the trip (the link was lost)"}
    (run / "metadata.json").write_text(json.dumps(meta))
    text = report_page([load_run(run)]).html()
    assert "safety trip: link_loss at 0.68 s (no sample for 200 ms); not a host stall" in text
    assert "unconfirmed: no sample came after the trip (the link was lost)" in text and ">NO<" not in text


def test_a_run_stopped_on_request_says_so_with_the_time(tmp_path, make_run):
    stop = {"t_s": 7.8, "reason": "stop_request", "detail": "SIGINT"}
    text = report_page([load_run(make_run(tmp_path, "r", events=[stop], requested_s=30.0))]).html()
    assert "stop request (SIGINT) at 7.80 s" in text and "7.80 s of the 30 s asked" in text


def test_a_run_recorded_before_the_time_ran_was_kept_reports_its_first_events_time(tmp_path, make_run):
    trip = {"t_s": 6.5, "reason": "force_limit", "detail": "9 N"}
    text = report_page([load_run(make_run(tmp_path, "r", events=[trip]))]).html()  # duration_s: as asked
    assert "6.50 s of the 13.496 s asked" in text  # the record's end: 3 cycles of 4 s after 1 s, and 0.5 s


def test_a_torque_sensor_is_named_as_one_and_a_flat_one_is_said_not_drawn(tmp_path, make_run):
    run = load_run(make_run(tmp_path, "r", plant="finger_extensor", sensor=("patient_torque_nm", "torque", "nm"),
                            flat_sensor=True))
    page = report_page([run])
    text = page.html()
    assert run.sensors == {} and run.flat_sensors == {"patient_torque_nm": 0.0}
    assert "patient torque [N m]: 0 N m throughout the session (not drawn" in text
    head = text.split("<table>")[-1].split("</thead>")[0]
    assert "peak patient" not in head and "peak contact" not in head  # no column of a sensor that never moved
    assert "force / sensor" not in text and "contact_force_n" not in text
    assert "patient torque [N m] on adc0 (20 counts per N m, offset 0 counts)" in text


def test_names_in_the_report_are_words_with_units_not_column_names(tmp_path, make_run):
    text = report_page([load_run(make_run(tmp_path, "r"))]).html()
    head = text.split("<table>")[-1].split("</thead>")[0]
    assert "peak contact force [N]" in head and "contact_force_n" not in head
    assert "applied_duty0_ratio" not in text.split('<script type="application/octet-stream"')[0].split("</div>")[-1]
    import json
    figs = [json.loads(part.split(">", 1)[1].split("</script>")[0].replace("<\\/", "</"))
            for part in text.split('<script type="application/json"')[1:]]
    names = {tr.get("name") for f in figs for tr in f["data"]}
    assert "applied duty, channel 0" in names and "applied_duty0_ratio" not in names
    for f in figs:  # every y axis has a unit
        yaxes = [v for k, v in f["layout"].items() if k.startswith("yaxis")]
        assert yaxes and all(y.get("title", {}).get("text") for y in yaxes), f["layout"].get("title")


@pytest.mark.parametrize(("force", "says", "never"), [
    ({"max_force_n": 40.0, "force_sensor": None, "firmware_force_limit_counts": 1023,
      "note": "A0 is not a force sensor: the firmware force limit is off"},
     "no force sensor: A0 is not a force sensor", "1023"),
    ({"max_force_n": 10.0, "force_sensor": "contact_force_n", "calibration": None,
      "linear_map": {"counts_per_n": 51.2, "offset_counts": 3.0}, "firmware_force_limit_counts": 515},
     "linear map of the config: 51.2 counts/N, offset 3 counts (no calibration file); limit 10 N = 515 counts", "{"),
    ({"max_force_n": 10.0, "force_sensor": "contact_force_n", "firmware_force_limit_counts": 600,
      "calibration": {"file": "calibrations/fsr7.toml", "sensor_id": "fsr-7", "circuit": "divider",
                      "model": "power_law", "coefficients": [1.0, 2.0], "tare_counts": 4, "fit_rms_n": 0.0812,
                      "hysteresis_pct_fs": 4.5, "max_calibrated_force_n": 20.0, "calibrated_at": "2026-10-30"}},
     "calibrations/fsr7.toml: sensor fsr-7, power_law model, fit RMS 0.0812 N, hysteresis 4.5 % FS, calibrated up to "
     "20 N, calibrated 2026-10-30; limit 10 N = 600 counts", "'file'"),
])
def test_the_force_calibration_reads_as_a_sentence(force, says, never):
    from rehab_hil.report.build import force_calibration_text

    text = force_calibration_text(force)
    assert says in text and never not in text and "{" not in text


def test_the_progress_table_has_each_sessions_stop_and_the_stiffness_unit(tmp_path, make_run):
    trip = {"t_s": 6.5, "reason": "force_limit", "detail": "9 N"}
    runs = [
        load_run(_with_twin(make_run(tmp_path, "20261101T0900Z-a", requested_s=13.5), 1.0)),
        load_run(_with_twin(make_run(tmp_path, "20261108T0900Z-a", events=[trip], requested_s=30.0), 1.6))]
    rows = progress_rows(runs)
    assert [r["stopped"] for r in rows] == ["the duration was reached", "safety trip: force_limit at 6.50 s (9 N)"]
    assert rows[1]["ran_s"] == 6.5
    head = report_page(runs).html().split("<table>")[1].split("</thead>")[0]
    assert "<th class=\"l\">stopped</th>" in head and "interaction stiffness [N m/rad]" in head
