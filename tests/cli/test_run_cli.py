"""``rehab-hil run`` end to end: a lockstep session with recording, user errors, and SIGTERM
putting a real-time session into the safe state before the exit."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from rehab_hil.cli import main
from rehab_hil.interchange import read_csv

ROOT = Path(__file__).resolve().parents[2]
CONFIG = ROOT / "configs" / "finger_extensor.toml"


@pytest.mark.slow
def test_run_lockstep_session_records_and_summarises(tmp_path, capsys):
    code = main(["run", "--config", str(CONFIG), "--device", "sim", "--lockstep", "--duration", "1.0",
                 "--record", str(tmp_path), "--no-display"])
    out = capsys.readouterr().out
    assert code == 0, out
    assert "duration reached" in out and "tracking mae" in out and "missed cycles" in out
    (run_dir,) = tmp_path.iterdir()  # --record DIR makes one new run directory per run
    rec = read_csv(run_dir / "run.csv")
    assert len(rec.t) >= 1000 and "iris_angle_reference_deg" in rec.signals
    assert (run_dir / "run.mcap").stat().st_size > 0


def test_run_refuses_a_bad_duration_and_a_config_without_a_session(tmp_path, capsys):
    assert main(["run", "--config", str(CONFIG), "--duration", "-1"]) == 2
    bad = tmp_path / "no_session.toml"
    bad.write_text(CONFIG.read_text().split("[rig.session]")[0])
    assert main(["run", "--config", str(bad), "--device", "sim"]) == 2
    err = capsys.readouterr().err
    assert "--duration" in err and "[rig.session]" in err


@pytest.mark.slow
def test_sigterm_trips_the_safe_state_and_exits_after_the_summary(tmp_path):
    proc = subprocess.Popen([sys.executable, "-m", "rehab_hil.cli", "run", "--config", str(CONFIG), "--device", "sim",
                             "--lockstep", "--duration", "600", "--record", str(tmp_path), "--no-display"],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, cwd=ROOT)
    try:
        deadline = time.monotonic() + 120
        while time.monotonic() < deadline:  # the loop runs once rows appear (flushed every 100 ms)
            found = list(tmp_path.glob("*/run.csv"))  # the run's own directory under --record
            if found and found[0].stat().st_size > 5000:
                csv = found[0]
                break
            assert proc.poll() is None, proc.communicate()
            time.sleep(0.1)
        os.kill(proc.pid, signal.SIGTERM)
        out, err = proc.communicate(timeout=60)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.communicate()
    assert proc.returncode == 128 + signal.SIGTERM, err  # the shell's convention, as for Ctrl-C (130)
    assert "stop_request" in out and "SIGTERM" in out
    assert "device PWM off at end" in out and "yes" in out.split("device PWM off at end")[1].splitlines()[0]
    read_csv(csv)  # the recording is complete and readable
    meta = json.loads((csv.parent / "metadata.json").read_text())
    assert meta["safety_events"][0]["reason"] == "stop_request" and meta["pwm_off_at_end"]  # written at the end
