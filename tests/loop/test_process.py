"""A real-time session's loop runs in a process of its own (spawned, one thread, memory locked where allowed)
and either side's death leaves the rig safe: a killed loop process is a safety event with ESTOP sent from the
session's process; a killed session's process is seen by the loop process, which stops the rig itself. A
session's process that stalls loses nothing the ring holds; one that stalls longer than the ring trips the
loop rather than leave a hole in the recording."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest

from rehab_hil.devices.starvation import process_tree
from rehab_hil.loop.records import SampleRecord
from rehab_hil.protocol import Status
from rehab_hil.rig_recording import read_recording
from rehab_hil.service.features.base import Feature
from rehab_hil.service.session import open_session
from rehab_hil.testing import config_with_lines

ROOT = Path(__file__).resolve().parents[2]
FE = ROOT / "configs" / "finger_extensor.toml"


@pytest.fixture
def slow_watchdog(tmp_path: Path) -> Path:
    """The Finger Extensor with a 1 s watchdog and link-loss budget: a loaded test machine's own stalls of
    the simulated device (not what these tests are about) trip nothing."""
    return config_with_lines(FE, tmp_path / "finger_extensor.toml",
                             {"watchdog_ms = 50 ": "watchdog_ms = 1000 ",
                              "link_loss_periods = 50 ": "link_loss_periods = 1000 "})


def _when_running(session, then) -> threading.Thread:
    """Call ``then(loop)`` once the session's loop process has started and taken its first samples."""
    def watch() -> None:
        deadline = time.monotonic() + 120
        while time.monotonic() < deadline:
            loop = session.loop
            if loop is not None and getattr(loop, "pid", None) and loop.progress.samples > 200:
                then(loop)
                return
            time.sleep(0.01)
    th = threading.Thread(target=watch, daemon=True)
    th.start()
    return th


def test_a_real_time_session_runs_its_loop_in_another_process_with_one_thread(slow_watchdog, tmp_path) -> None:
    with open_session(slow_watchdog, "sim", controller="pid", record=tmp_path) as s:
        result = s.run(1.5)
    rt = result.realtime
    assert rt is not None and f"loop process {os.getpid()}" not in rt.process
    assert "1 thread(s)" in rt.process and rt.process.startswith("loop process ")
    rows = read_recording(result.files[0]).recording.t.size
    assert result.samples > 1000 and rows == result.samples  # every sample the loop took, recorded
    assert result.sinks["ring"]["dropped"] == 0 and result.sinks["recorder"]["dropped"] == 0


def test_a_killed_loop_process_is_a_safety_event_and_the_session_sends_estop(slow_watchdog) -> None:
    with open_session(slow_watchdog, "sim", controller="pid") as s:
        _when_running(s, lambda loop: os.kill(loop.pid, signal.SIGKILL))
        result = s.run(30.0)
        after = s.hw.read_sample(2.0)  # the device, after the session's ESTOP
    (ev,) = result.events
    assert ev.reason == "loop_process_lost" and "killed by signal 9" in ev.detail and "ESTOP sent" in ev.detail
    assert result.ran_s < 30.0 and after is not None
    assert after.duty0 == 0 and not after.status & Status.PWM_ENABLED


class _StallOnce(Feature):
    """A sink of the session's process that blocks once for ``stall_s`` (critical: a recording's stand-in)."""

    name = "stall"

    def __init__(self, after: int, stall_s: float) -> None:
        self.after, self.stall_s, self.seen = after, stall_s, 0
        self.critical, self.dropped, self.error, self.on_failure = True, 0, None, None

    def sinks(self):
        return [self]

    def offer(self, record) -> bool:
        if type(record) is SampleRecord:
            self.seen += 1
            if self.seen == self.after:
                time.sleep(self.stall_s)
        return True

    def wake(self) -> None:
        pass

    def drain(self) -> None:
        pass


def test_a_stall_of_the_sessions_process_shorter_than_the_ring_loses_nothing(slow_watchdog) -> None:
    stall = _StallOnce(after=300, stall_s=0.3)
    with open_session(slow_watchdog, "sim", controller="pid", features=(stall,)) as s:
        result = s.run(2.0)
    assert result.events == [] and stall.seen == result.samples
    assert result.sinks["ring"] == {**result.sinks["ring"], "dropped": 0, "overflow": 0}


def test_a_stall_longer_than_the_ring_trips_the_loop_instead_of_losing_records(slow_watchdog) -> None:
    stall = _StallOnce(after=300, stall_s=1.5)
    with open_session(slow_watchdog, "sim", controller="pid", features=(stall,), ring_s=0.4) as s:
        result = s.run(10.0)
    assert result.events[0].reason == "sink_failure" and "behind the ring" in result.events[0].detail
    assert result.pwm_off_at_end and result.ran_s < 5.0


def test_a_killed_sessions_process_leaves_the_loop_process_to_stop_the_rig(slow_watchdog, tmp_path) -> None:
    cli = subprocess.Popen([sys.executable, "-m", "rehab_hil.cli", "run", "--config", str(slow_watchdog), "--device",
                            "sim", "--duration", "60", "--no-display", "--home", "none", "--controller", "pid"],
                           stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True, cwd=ROOT)
    try:
        loop_pid = _child_running(cli.pid, "rehab_hil.loop.process", timeout_s=120)
        _running_fifo(loop_pid, timeout_s=120)  # it has its job and the link: its loop runs
        time.sleep(0.5)
        device_pid = _child_running(cli.pid, "sim_device", timeout_s=5)
        cli.kill()
        cli.wait(10)
        _gone(loop_pid, timeout_s=10)  # the loop process saw its parent go, stopped the rig and ended
        err = cli.stderr.read()
        assert "rehab-hil loop: the session's process ended" in err and "PWM 0 and ESTOP sent" in err
    finally:
        cli.kill()
        for pid in (locals().get("device_pid"), locals().get("loop_pid")):
            if pid:
                try:
                    os.kill(pid, signal.SIGKILL)
                except ProcessLookupError:
                    pass


def _child_running(parent: int, needle: str, timeout_s: float) -> int:
    """A process under ``parent`` (a child, or a child of its zygote: ``rehab_hil.launch``) running ``needle``."""
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        for pid in process_tree(parent)[1:]:
            try:
                if needle in Path(f"/proc/{pid}/cmdline").read_text():
                    return pid
            except OSError:
                continue
        time.sleep(0.05)
    raise AssertionError(f"no child process running {needle}")


def _running_fifo(pid: int, timeout_s: float) -> None:
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        if os.sched_getscheduler(pid) == os.SCHED_FIFO:
            return
        time.sleep(0.05)
    raise AssertionError(f"process {pid} never ran SCHED_FIFO")


def _gone(pid: int, timeout_s: float) -> None:
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        try:
            state = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0]
        except OSError:
            return
        if state in "ZX":
            return
        time.sleep(0.05)
    raise AssertionError(f"process {pid} still runs")


def test_a_controller_the_loop_process_cannot_import_runs_in_the_sessions_process_said_so(slow_watchdog) -> None:
    import sys
    import types

    from rehab_hil.controllers import build_controller
    from rehab_hil.loading import load_config
    from rehab_hil.loop.controllers import SAFE_COMMAND

    ghost = types.ModuleType("ghost_controllers")  # importable here only: no file on any path

    class Quiet:
        def __init__(self, claims) -> None:
            self.claims = claims

        def reset(self) -> None:
            pass

        def __call__(self, t_s, state):
            return SAFE_COMMAND

    Quiet.__module__, Quiet.__qualname__ = ghost.__name__, "Quiet"
    ghost.Quiet = Quiet
    sys.modules[ghost.__name__] = ghost
    try:
        with open_session(slow_watchdog, "sim", controller=Quiet(build_controller(load_config(FE), "pid").claims)) as s:
            result = s.run(1.0)
    finally:
        del sys.modules[ghost.__name__]
    assert result.events == [] and result.samples > 500
    assert result.realtime.process.startswith("the session's process (the loop process could not load its job: ")
    assert "ghost_controllers" in result.realtime.process


def test_a_terminals_ctrl_c_stops_the_loop_through_the_safe_state_not_by_killing_it(slow_watchdog) -> None:
    cli = subprocess.Popen([sys.executable, "-m", "rehab_hil.cli", "run", "--config", str(slow_watchdog), "--device",
                            "sim", "--duration", "60", "--no-display", "--home", "none", "--controller", "pid"],
                           stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, cwd=ROOT,
                           start_new_session=True)
    try:
        loop_pid = _child_running(cli.pid, "rehab_hil.loop.process", timeout_s=120)
        _running_fifo(loop_pid, timeout_s=120)
        os.killpg(cli.pid, signal.SIGINT)  # what a terminal does: the whole foreground process group
        out, _ = cli.communicate(timeout=60)
    finally:
        cli.kill()
    assert cli.returncode == 130 and "safety stop_request" in out and "SIGINT" in out
    assert "loop_process_lost" not in out and "PWM off at end" in out
    assert next(x for x in out.splitlines() if "PWM off at end" in x).split("│")[2].strip() == "yes"


def test_stricter_thermal_values_reach_a_loop_process_through_its_mailbox(tmp_path) -> None:
    """The twin's stricter values (here a room 7 C warmer, handed over as the safety feature does) are taken
    by the supervisor in the loop process at its next cycle: the estimate reads the warmer room from then on."""
    from rehab_hil.loading import load_config
    from rehab_hil.service.features.safety_thermal import Tightener

    sma = config_with_lines(ROOT / "configs" / "sma_exoskeleton.toml", tmp_path / "sma.toml",
                            {"watchdog_ms = 100 ": "watchdog_ms = 1000 ",
                             "link_loss_periods = 100 ": "link_loss_periods = 1000 "})
    change = Tightener(load_config(sma), ["sma.ambient_c"], 0.001).tightening(0.0, {"sma.ambient_c": 30.0})
    posted: list[bool] = []
    with open_session(sma, "sim", controller="pid", home="none") as s:
        _when_running(s, lambda loop: posted.append(loop.tighten_thermal(change)))
        result = s.run(3.0)
    assert posted == [True] and result.events == []
    (taken,) = result.thermal_changes
    assert taken["values"] == {"sma.ambient_c": 30.0} and 0.2 < taken["t_s"] < 3.0
    assert taken["temperature_before_c"] == pytest.approx(23.0, abs=0.1)  # at rest: the room (the PID's closed hold)
    assert taken["temperature_after_c"] == pytest.approx(30.0, abs=0.1)
