"""Kill test: ``rehab-hil run --record DIR`` is SIGKILLed mid-session (no handler, no cleanup runs).

The recorder flushes the CSV and the MCAP every 0.1 s in whole lines / finished chunks, so what is
on disk must open as it is: the CSV with ``read_csv``, the MCAP without its summary and footer with
``read_mcap``, holding every sample up to the last flush, the two files agreeing sample for sample.
The lockstep device never drops a sample, so "every sample" means sample_index 0, 1, 2, ... with no gap.
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from rehab_hil.interchange import read_csv
from rehab_hil.service.recorder import read_mcap

from .conftest import CONFIG

pytestmark = [pytest.mark.slow, pytest.mark.timeout(180)]

ROWS_BEFORE_KILL = 600


def data_lines(path: Path) -> int:
    try:
        with path.open("rb") as fh:
            return max(0, sum(1 for _ in fh) - 1)
    except FileNotFoundError:
        return 0


def run_file(out: Path, name: str) -> Path:
    """``--record DIR`` writes into a fresh run directory inside DIR (service/run_dir.py)."""
    found = sorted(out.glob(f"*/{name}")) or [out / name]
    return found[-1]


def test_sigkill_mid_recording_leaves_csv_and_mcap_readable_with_every_flushed_sample(tmp_path: Path) -> None:
    out = tmp_path / "rec"
    log = (tmp_path / "stdout.txt").open("wb")
    argv = [sys.executable, "-m", "rehab_hil.cli", "run", "--config", str(CONFIG), "--device", "sim", "--lockstep",
            "--duration", "120", "--record", str(out), "--no-display"]
    # its own process group: the service and the device it spawns are ours to clean up by that id
    proc = subprocess.Popen(argv, stdout=log, stderr=subprocess.STDOUT, start_new_session=True)
    try:
        deadline = time.monotonic() + 120
        while data_lines(run_file(out, "run.csv")) < ROWS_BEFORE_KILL:
            assert proc.poll() is None, f"the service ended early: {(tmp_path / 'stdout.txt').read_text()[-2000:]}"
            assert time.monotonic() < deadline, "the service did not record in time"
            time.sleep(0.05)
        os.kill(proc.pid, signal.SIGKILL)
        assert proc.wait(timeout=10) == -signal.SIGKILL
    finally:
        try:
            os.killpg(proc.pid, signal.SIGKILL)  # the orphaned device, if stdin EOF has not ended it yet
        except ProcessLookupError:
            pass
        proc.wait(timeout=10)
        log.close()

    csv = read_csv(run_file(out, "run.csv"))  # raises CsvError (with the line) if the kill left a torn file
    idx = csv["sample_index"].astype(np.int64)
    assert len(idx) >= ROWS_BEFORE_KILL
    np.testing.assert_array_equal(idx, np.arange(idx[0], idx[0] + len(idx)))  # no sample missing
    assert np.all(np.diff(csv.t) > 0)

    mcap_idx = np.array([int(m["sample_index"]) for topic, _, m in read_mcap(run_file(out, "run.mcap"))
                         if topic == "/rig/sample"], dtype=np.int64)
    assert len(mcap_idx) >= ROWS_BEFORE_KILL - 200  # within one flush period of the CSV
    n = min(len(idx), len(mcap_idx))
    np.testing.assert_array_equal(mcap_idx[:n], idx[:n])  # the same samples, in the same order
    assert abs(len(idx) - len(mcap_idx)) <= 200  # the kill can fall between the CSV and the MCAP flush
