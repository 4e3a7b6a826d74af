"""A session's figures from its files (``rehab_hil.run_figures``) are the figures its summary and
metadata.json print, on recorded in-process Finger Extensor sessions; rows with no reference carry
none."""

from __future__ import annotations

import json
import threading
import time

import numpy as np
import pytest

from rehab_hil.interchange import read_csv
from rehab_hil.rig_recording import read_mcap_recording
from rehab_hil.run_figures import run_figures
from rehab_hil.service.session import open_session
from rehab_hil.testing import CONFIGS

FE = CONFIGS / "finger_extensor.toml"
REF = "iris_angle_reference_deg"


def _session(tmp_path, duration_s: float, **options):
    with open_session(FE, "inprocess", controller="pid", record=tmp_path, **options) as s:
        result = s.run(duration_s)
    return result, s.run_dir, json.loads((s.run_dir / "metadata.json").read_text())


def test_the_summarys_tracking_figures_are_those_of_run_csv_and_run_mcap(tmp_path):
    result, run, meta = _session(tmp_path, 2.0)
    assert result.tracking and meta["tracking"] == pytest.approx(result.tracking, rel=1e-12)
    for source in (run, run / "run.csv", run / "run.mcap"):
        assert run_figures(source)["tracking"] == pytest.approx(result.tracking, rel=1e-8), source
    rec = read_csv(run / "run.csv")
    ref = rec[REF]
    stopped = rec.t >= 2.0  # the rows after the session's end: the stop, PWM confirmed off
    assert stopped.sum() >= 1 and np.isnan(ref[stopped]).all()  # no reference, not 0 deg
    assert np.isnan(ref[0]) and np.isfinite(ref[1:][~stopped[1:]]).all()  # the first row: no command yet
    mcap, _ = read_mcap_recording(run / "run.mcap")
    np.testing.assert_array_equal(np.isnan(mcap[REF]), np.isnan(ref))


def test_a_step_run_reports_overshoot_rise_and_settling_as_its_file_gives_them(tmp_path):
    result, run, meta = _session(tmp_path, 2.0, reference="step")
    assert meta["reference"]["kind"] == "step" and meta["reference"]["start_deg"] == 0.0
    step = meta["step_response"]
    assert step == pytest.approx(result.step, rel=1e-12)
    assert step["target"] == pytest.approx(meta["reference"]["open_deg"])
    assert step["rise_time_s"] > 0 and step["overshoot"] >= 0 and 0 < step["settling_time_s"] < 2.0
    assert run_figures(run)["step_response"] == pytest.approx(step, rel=1e-8)


def test_a_session_of_cycles_has_each_cycles_figures_as_its_file_gives_them_and_no_step(tmp_path):
    result, run, meta = _session(tmp_path, 16.0)  # one 12 s cycle after a 3 s rest
    assert result.step == {} and meta["step_response"] is None and meta["reference"]["kind"] == "session"
    figures = run_figures(run)
    assert figures["step_response"] is None and len(meta["session_cycles"]) == len(figures["cycles"]) == 1
    for key, value in figures["cycles"][0].items():  # the meter's figures are the file's
        assert meta["session_cycles"][0][key] == pytest.approx(value, rel=1e-8, abs=1e-12), key


def test_a_stopped_session_records_the_time_it_ran_not_the_time_asked(tmp_path):
    with open_session(FE, "inprocess", controller="pid", record=tmp_path) as s:
        def stop_at_half_a_second() -> None:  # as Ctrl-C would, from another thread
            while s.progress.t_s < 0.5:
                time.sleep(0.001)
            s.request_stop("SIGINT")

        stopper = threading.Thread(target=stop_at_half_a_second, daemon=True)
        stopper.start()
        result = s.run(3.0)
        stopper.join(5.0)
    meta = json.loads((s.run_dir / "metadata.json").read_text())
    assert result.events[0].reason == "stop_request"
    assert meta["requested_duration_s"] == 3.0 and meta["duration_s"] == pytest.approx(result.ran_s)
    assert 0.5 <= meta["duration_s"] < 2.9 and meta["duration_s"] == pytest.approx(result.events[0].t_s, abs=0.002)
