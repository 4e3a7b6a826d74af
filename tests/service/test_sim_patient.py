"""Sessions with a simulated patient: ``--sim-patient`` on the in-process rig, the Python device on a
pty and the firmware in simavr; ``sim_truth.csv`` beside the recording of a simulated device and never
on a real rig's path; an assist-as-needed session with a capable patient lowers the assistance."""

from __future__ import annotations

import json

import numpy as np
import pytest

from rehab_hil.controllers import Reference
from rehab_hil.devices import avr_device
from rehab_hil.devices.spawn import spawn_sim_device
from rehab_hil.patient.truth import TRUTH_FILE, read_truth
from rehab_hil.service.session import SessionError, open_session
from tests.conftest import ROOT

from .conftest import CONFIG

CAPABLE = ROOT / "profiles" / "sim" / "capable.toml"


def test_assist_as_needed_with_a_capable_patient_lowers_the_assistance_and_keeps_the_truth(cfg, tmp_path):
    ref = Reference.session(cfg)
    with open_session(CONFIG, "inprocess", controller="assist_as_needed", sim_patient=CAPABLE,
                      record=tmp_path) as s:
        res = s.run(ref.first_open_s + 6 * ref.period_s + 0.5)  # a streak of four successes, then forgetting
        run_dir = s.run_dir
    assert res.events == [] and res.pwm_off_at_end
    cycles = json.loads((run_dir / "metadata.json").read_text())["session_cycles"]
    ratio = [c["assistance_ratio"] for c in cycles]
    assert len(ratio) == 6
    assert all(np.diff(ratio) < 0) and ratio[-1] < 0.5 * ratio[0]  # less and less of the work
    assert np.mean([c["success"] for c in cycles]) >= 0.8  # and the patient still reaches the targets
    meta = json.loads((run_dir / "metadata.json").read_text())
    assert meta["sim_patient"]["config_path"].endswith("capable.toml") and meta["sim_patient"]["truth"] == TRUTH_FILE
    truth = read_truth(run_dir / TRUTH_FILE)
    assert truth["t_s"][-1] == pytest.approx(ref.first_open_s + 6 * ref.period_s + 0.5, abs=0.05)
    assert set(truth) >= {"patient_effort", "patient_voluntary_nm", "patient_axis_torque_nm", "iris_angle_rad"}
    # the host's torque sensor reads the patient's true torque (its quantisation apart)
    est = [c["patient_torque_open_nm"] for c in cycles]
    assert np.max(np.abs(est)) > 0.01


def test_the_python_device_on_a_pty_writes_the_truth_beside_the_recording(tmp_path):
    with open_session(CONFIG, "sim", lockstep=True, controller="pid", sim_patient=CAPABLE, record=tmp_path,
                      sample_timeout_s=10.0) as s:
        res = s.run(3.0)
        run_dir = s.run_dir
    assert res.events == []
    truth = read_truth(run_dir / TRUTH_FILE)
    assert len(truth["t_s"]) > 250 and truth["t_s"][-1] <= 3.1  # the loop's session only: homing's clock restarted


def test_a_real_rigs_path_has_no_truth_file_and_refuses_a_simulated_patient(tmp_path):
    with spawn_sim_device(CONFIG, clock="lockstep") as dev:  # a serial path: to the host, a real board
        with pytest.raises(SessionError, match="sim_patient"):
            open_session(CONFIG, dev.port, lockstep=False, sim_patient=CAPABLE)
        with open_session(CONFIG, dev.port, controller="pid", record=tmp_path, realtime=False,
                          sample_timeout_s=10.0) as s:
            s.run(0.5)
            run_dir = s.run_dir
    assert (run_dir / "metadata.json").exists() and not (run_dir / TRUTH_FILE).exists()
    assert json.loads((run_dir / "metadata.json").read_text()).get("sim_patient") is None


def test_a_bad_patient_file_is_one_line_naming_the_file_and_the_key(tmp_path):
    bad = tmp_path / "bad.toml"
    bad.write_text('patient_id = "x"\n[voluntary]\nflexion_capacity_nm = -1.0\nextension_capacity_nm = 1.0\n'
                   "stiffness_nm_per_rad = 1.0\n")
    with pytest.raises(SessionError, match=r"bad.toml: voluntary.flexion_capacity_nm"):
        open_session(CONFIG, "inprocess", sim_patient=bad)


@pytest.mark.slow
@pytest.mark.firmware
@pytest.mark.skipif(avr_device.unavailable_reason() is not None, reason=str(avr_device.unavailable_reason()))
def test_assist_as_needed_runs_on_the_firmware_in_simavr_with_a_patient_in_lockstep(tmp_path):
    with open_session(CONFIG, "avr", lockstep=True, controller="assist_as_needed", sim_patient=CAPABLE,
                      record=tmp_path, sample_timeout_s=10.0, realtime=False) as s:
        res = s.run(4.0)
        run_dir = s.run_dir
    assert res.events == [] and res.pwm_off_at_end
    truth = read_truth(run_dir / TRUTH_FILE)
    assert len(truth["t_s"]) > 300
