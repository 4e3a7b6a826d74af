"""The custom-subscriber example in docs/ runs and prints what a live publisher sends."""

from __future__ import annotations

import subprocess
import sys
import threading
import time
from collections.abc import Callable
from pathlib import Path

import zenoh

from rehab_hil.loop.controllers import Command
from rehab_hil.loop.estimation import State
from rehab_hil.loop.records import SampleRecord
from rehab_hil.protocol import Sample
from rehab_hil.telemetry import NetworkConfig, TelemetryPublisher
from rehab_hil.telemetry.rig import RigTelemetry


def test_the_docs_example_prints_the_samples_it_receives(client: Callable[..., zenoh.Session], hub: int,
                                                         wait, docs_dir: Path) -> None:
    example = docs_dir / "telemetry_example.py"
    assert "subscribe(" in (docs_dir / "telemetry.md").read_text()  # the doc shows the API it links to
    stop = threading.Event()
    with TelemetryPublisher(client(), "demo", batch=5) as pub:
        proc = subprocess.Popen([sys.executable, str(example), "demo", "--port", str(hub), "--count", "5"],
                                stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)

        def feed() -> None:
            i = 0
            while not stop.wait(0.01):
                s = Sample(i, i, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0)
                pub.offer(SampleRecord(0.0, i * 1e-3, s, State(0.0, 0.5, 0.0, {}), Command((0.25, 0.0)), i, 30.0))
                i += 1

        th = threading.Thread(target=feed)
        th.start()
        try:
            out, err = proc.communicate(timeout=60)
        finally:
            stop.set()
            th.join()
    assert proc.returncode == 0, err
    lines = out.strip().splitlines()
    assert lines[-1] == "received 5 samples, 0 batches missing"
    assert "angle 28.65 deg, duty 0.250, temperature 30.0 C" in lines[0]
    idx = [int(line.split()[1].rstrip(":")) for line in lines[:-1]]
    assert idx == [0, 1, 2, 3, 4]  # the rig's first samples (the publisher's history), in order


def test_the_docs_example_started_before_its_rig_waits_for_it(unused_port: int, docs_dir: Path) -> None:
    """Started first, the example waits for the rig's hub instead of failing to connect."""
    proc = subprocess.Popen([sys.executable, str(docs_dir / "telemetry_example.py"), "early", "--port",
                             str(unused_port), "--count", "5"], stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                            text=True)
    try:
        time.sleep(1.0)
        assert proc.poll() is None, proc.communicate()  # still waiting, not dead
        with RigTelemetry("early", {}, NetworkConfig(port=unused_port)) as rig:
            assert rig.role == "hub"
            for i in range(20):
                s = Sample(i, i, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0)
                rig.sink.offer(SampleRecord(0.0, i * 1e-3, s, State(0.0, 0.5, 0.0, {}), Command((0.25, 0.0)), i,
                                            30.0))
            out, err = proc.communicate(timeout=60)
    finally:
        if proc.poll() is None:
            proc.kill()
    assert proc.returncode == 0, err
    lines = out.strip().splitlines()
    assert lines[-1] == "received 5 samples, 0 batches missing"
    assert [int(line.split()[1].rstrip(":")) for line in lines[:-1]] == [0, 1, 2, 3, 4]
