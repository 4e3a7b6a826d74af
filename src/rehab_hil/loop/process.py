"""The real-time loop in a process of its own: nothing else in it holds its interpreter lock.

A real-time session's loop runs in a process of its own (``LoopProcess``; forked by ``rehab_hil.launch``'s
warm zygote) that holds the link (the open
serial port, handed over as a file descriptor), the controller, the estimator and the supervisor, and
nothing else: no helper thread runs Python there. It asks for SCHED_FIFO and locks its memory. Every
sample, command and event goes into the shared-memory ring (``loop.ring``); the session's process reads
the ring on a thread of its own and hands the records to the figures, the feeds and the sinks
(``loop.dispatch``: the recorder, zenoh, Foxglove, the twin), which may stall for as long as the ring
holds (``ring.RING_S``) without losing a record. What flows back (a stop request, a learned table, stricter
values for the temperature estimate) goes through the mailbox (``loop.mailbox``), looked at once a cycle.

Either side's death is a safety event with the PWM off: the loop process watches the session's process
(a pidfd: its parent is the zygote) every ``PARENT_CHECK_EVERY`` cycles and, if it is gone, trips
(``session_lost``), sends PWM 0 and ESTOP and ends; the session's process sees the loop process end
without its report and sends ESTOP itself over its copy of the link (``loop_process_lost``, with the
exit status).
"""

from __future__ import annotations

import contextlib
import dataclasses
import os
import pickle
import select
import signal
import subprocess
import sys
import threading
import time
from dataclasses import dataclass
from typing import Any

from rehab_hil import launch
from rehab_hil.hardware.interface import HardwareError
from rehab_hil.loop.dispatch import Dispatch
from rehab_hil.loop.kworkers import KworkerBoost, loop_processes_running
from rehab_hil.loop.mailbox import Mailbox, MailboxFull
from rehab_hil.loop.records import CommandRecord, EventRecord, SampleRecord
from rehab_hil.loop.ring import RING_S, RecordRing, RingReader, RingWriter
from rehab_hil.loop.runner import LoopReport, LoopService
from rehab_hil.loop.supervisor import SafetyEvent
from rehab_hil.loop.timing import HELPER_NICE, lock_memory, threads_niced

__all__ = ["LoopJob", "LoopProcess", "RingOutlet", "can_cross"]

PUMP_IDLE_S = 0.002  # the ring reader's sleep when the ring is empty (a record waits at most this long)
LINK_EVERY = 100  # commands between writes of the link's counters for the live views
Child = subprocess.Popen[bytes] | launch.ForkedChild
PARENT_CHECK_EVERY = 10  # cycles between the loop process's looks at the session's
START_TIMEOUT_S = 120.0  # spawning, importing and loading the controller's kernels (a busy machine: seconds)
END_TIMEOUT_S = 30.0  # from the end of the loop's duration to its report (the shutdown's confirmation: < 1 s)


class RingOutlet:
    """The loop process's outlet: each record into the ring (``loop.runner.Outlet``), and every
    ``LINK_EVERY`` commands the link's counters."""

    def __init__(self, writer: RingWriter, link_stats: Any) -> None:
        self.writer, self.link_stats = writer, link_stats
        self._sample, self._command = writer.sample, writer.command
        self.n = 0

    def cycle(self, samples: list[SampleRecord], command: CommandRecord | None) -> None:
        for rec in samples:
            self._sample(rec)
        if command is not None:
            self._command(command)
            self.n += 1
            if self.n % LINK_EVERY == 0:
                self.writer.link(self.link_stats)

    def events(self, events: list[EventRecord]) -> None:
        for rec in events:
            self.writer.event(rec)


class ProcessMail:
    """The loop process's look at the session, once a cycle: messages in the mailbox, its parent, and
    (``writer`` given) a ring that overflowed."""

    def __init__(self, mailbox: Mailbox, parent_pid: int, writer: RingWriter | None = None) -> None:
        self.mailbox, self.parent_pid, self.writer = mailbox, parent_pid, writer
        self.n = 0
        try:  # a descriptor of the session's process, readable once it has ended (its parent may be the zygote)
            self.parent_fd: int | None = os.pidfd_open(parent_pid)
        except ProcessLookupError:
            self.parent_fd = None

    def parent_alive(self) -> bool:
        return self.parent_fd is not None and not select.select([self.parent_fd], [], [], 0)[0]

    def check(self, loop: LoopService) -> None:
        if self.mailbox.waiting():
            for message in self.mailbox.take():
                _act(loop, message)
        self.n += 1
        if self.n % PARENT_CHECK_EVERY:
            return
        if not self.parent_alive():
            loop.request_stop("the session's process ended (it reads the ring: recording, telemetry, the twin)",
                              "session_lost")
        elif self.writer is not None and self.writer.overflow:
            loop.request_stop(f"the session's readers fell {self.writer.capacity} records behind the ring "
                              "(its length): the recording would have a hole", "sink_failure")


def _act(loop: LoopService, message: tuple[Any, ...]) -> None:
    """One message from the session: ("stop", reason, kind), ("table", table, retune) or ("thermal",
    tightening): stricter values for the supervisor's temperature estimate (``loop/thermal.py``)."""
    if message[0] == "stop":
        loop.request_stop(message[1], message[2])
    elif message[0] == "table":
        loop.controller.offer_table(message[1], message[2])  # type: ignore[attr-defined]
    elif message[0] == "thermal":
        loop.tighten_thermal(message[1])


@dataclass
class LoopJob:
    """Everything the loop process needs, pickled into its stdin when it is started."""

    link: dict[str, Any]  # the connected SerialHardware's state (``link_state``)
    fd: int  # its port's file descriptor, passed to the process (the same number there)
    device: Any  # a local simulated device's process (``DeviceProcessView``), or None
    configure: Any
    controller: Any
    estimator: Any
    supervisor: Any
    period_s: float
    ring: str
    mailbox: str
    parent_pid: int
    run: dict[str, Any]  # LoopService.run's keyword arguments
    trip_on_overflow: bool = False


def can_cross(hw: Any, controller: Any) -> str:
    """Why this session's loop cannot run in a process of its own ("" when it can): a link that is not a
    serial port (the in-process device is lockstep by nature), or a controller that does not pickle."""
    import pickle

    if not hasattr(hw, "link_state"):
        return f"the {type(hw).__name__} link stays in the session's process"
    try:
        pickle.dumps(controller)
    except Exception as e:  # a test's own controller class defined where a spawned process cannot import it
        return f"its controller {type(controller).__name__} cannot be sent to a loop process ({type(e).__name__})"
    return ""


def main(argv: list[str] | None = None) -> int:
    """The loop process (``python -m rehab_hil.loop.process RESULT_FD``): the job from stdin, run, the report
    and the link's state back through ``RESULT_FD``."""
    from rehab_hil.hardware.serial_hw import SerialHardware

    result_fd = int((argv or sys.argv[1:])[0])
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # the session's process stops the loop, through the safe state
    try:
        job: LoopJob = pickle.load(sys.stdin.buffer)
    except Exception as e:  # a class this interpreter cannot import (a test's own controller): the session's
        with os.fdopen(result_fd, "wb") as out:  # process runs the loop itself; the link was not touched
            pickle.dump(("unloadable", f"{type(e).__name__}: {e}"), out)
        return 3
    hw = SerialHardware.handed_over(job.link, job.fd)
    hw.device_process = job.device
    report = _run(job, hw)
    try:
        with os.fdopen(result_fd, "wb") as out:
            pickle.dump((report, hw.link_state(), job.controller), out, protocol=pickle.HIGHEST_PROTOCOL)
    except OSError:  # nobody reads the report (the session's process is gone): say on the terminal how it ended
        first = report.events[0] if report.events else None
        how = f"{first.reason}: {first.detail}" if first is not None else report.stop_reason
        print(f"rehab-hil loop: the session's process ended; the loop stopped ({how}); the rig was left with "
              "PWM 0 and ESTOP sent", file=sys.stderr, flush=True)
    hw.close_handed()
    return 0


def _run(job: LoopJob, hw: Any) -> LoopReport:
    """Attach the ring and the mailbox, lock the memory, run the loop."""
    memory = lock_memory()
    ring, mailbox = RecordRing.attach(job.ring), Mailbox.attach(job.mailbox)
    writer = RingWriter(ring)
    loop = LoopService(hw, job.configure, job.controller, job.estimator, job.supervisor, job.period_s,
                       RingOutlet(writer, hw.stats),
                       ProcessMail(mailbox, job.parent_pid, writer if job.trip_on_overflow else None))
    signal.signal(signal.SIGTERM, lambda n, f: loop.request_stop("SIGTERM to the loop process", "stop_request"))
    report = loop.run(**job.run)
    if report.realtime is not None:
        where = f"loop process {os.getpid()}, memory {memory}, {threading.active_count()} thread(s)"
        report.realtime = dataclasses.replace(report.realtime, process=where)
    report.ring_overflow = writer.overflow
    return report


class RingLink:
    """The link's figures while a loop process holds it: the counters from the ring, the rest (latency)
    as the session's copy last knew them (the loop's report has the whole)."""

    def __init__(self, ring: RecordRing, hw: Any) -> None:
        self.ring, self.hw = ring, hw

    @property
    def stats(self) -> RingLink:
        return self

    def as_dict(self) -> dict[str, Any]:
        d = self.hw.stats.as_dict()
        if self.ring.buf is not None:
            d.update(self.ring.link_counts())
        d["bad_frames"] = {"all": d["bad_frames"]} if isinstance(d["bad_frames"], int) else d["bad_frames"]
        return d


class LoopProcess:
    """The session's handle on a loop process; ``run`` spawns it and returns its ``LoopReport``."""

    separate = True

    def __init__(self, hw: Any, configure: Any, controller: Any, estimator: Any, supervisor: Any, period_s: float,
                 dispatch: Dispatch, analog_names: tuple[str, ...], ring_s: float = RING_S,
                 trip_on_overflow: bool = False) -> None:
        """``trip_on_overflow``: a record lost for want of room in the ring stops the loop (a session that
        records must not go on with a hole in its recording)."""
        self.hw, self.configure, self.controller = hw, configure, controller
        self.estimator, self.supervisor, self.period_s = estimator, supervisor, period_s
        self.dispatch = dispatch
        self.ring = RecordRing.for_session(1.0 / period_s, ring_s)
        self.mailbox = Mailbox.create()
        self.reader = RingReader(self.ring, analog_names)
        self.overflow = 0
        self.trip_on_overflow = trip_on_overflow
        self.link = RingLink(self.ring, hw)
        self.pid: int | None = None
        self.local_service: LoopService | None = None  # the loop run here after all (``_here``)
        self._stop: tuple[str, str] | None = None
        self._done = threading.Event()

    @property
    def progress(self) -> Any:
        return self.dispatch.figures.progress

    @property
    def ring_s(self) -> float:
        """How long the session's process may stall without losing a record."""
        return self.ring.capacity * self.period_s / 2.5

    def request_stop(self, reason: str, kind: str = "stop_request") -> None:
        """Stop at the loop's next cycle through the safe state (any thread; before ``run``: at its start)."""
        self._stop = (reason, kind)
        if self.local_service is not None:
            self.local_service.request_stop(reason, kind)
            return
        try:
            self.mailbox.post(("stop", reason, kind), timeout_s=0.5, stop=True)
        except (MailboxFull, ValueError, TypeError):
            pass  # not taken yet: the loop's first look at the mail, or it has ended

    def offer_table(self, table: Any, retune: Any = None) -> bool:
        """A learned table for the controller's next swap window; False if the loop has not taken the
        ones before it (counted by the caller as late)."""
        if self.local_service is not None:
            self.controller.swap_table(table, retune)
            return True
        return self._post(("table", table, retune))

    def tighten_thermal(self, change: Any) -> bool:
        """Stricter values for the supervisor's temperature estimate, taken at the loop's next cycle (in a
        loop run here, straight away: the safety feature's feed calls it on the loop's thread); False if
        the loop has not taken the messages before it (the caller tries again)."""
        if self.local_service is not None:
            self.local_service.tighten_thermal(change)
            return True
        return self._post(("thermal", change))

    def _post(self, message: tuple[Any, ...]) -> bool:
        try:
            self.mailbox.post(message, timeout_s=0.5)
        except MailboxFull:
            return False
        return True

    def run(self, **run: Any) -> LoopReport:
        """Spawn the loop process with its job, read its ring until it ends, return its report. In real time
        the kernel's tty workers are raised meanwhile (``loop.kworkers``) and this process's threads (the
        ring's reader, the sinks) run at ``HELPER_NICE``: ahead of busy ordinary processes, never of the loop."""
        realtime = run.get("realtime", True)
        job = LoopJob(self.hw.link_state(), self.hw.fd, _view(self.hw), self.configure, self.controller,
                      self.estimator, self.supervisor, self.period_s, self.ring.name, self.mailbox.name, os.getpid(),
                      run, self.trip_on_overflow)
        boost = KworkerBoost().start() if realtime else None
        try:
            with threads_niced(HELPER_NICE) if realtime else contextlib.nullcontext(0):
                got = self._spawned(job, run)
        finally:
            if boost is not None:
                boost.stop(others_running=loop_processes_running(but=self.pid))
        if boost is not None and got.realtime is not None:
            got.realtime = dataclasses.replace(got.realtime, tty_workers=boost.note)
        return got

    def _spawned(self, job: LoopJob, run: dict[str, Any]) -> LoopReport:
        result_r, result_w = os.pipe()
        env = {**os.environ, "PYTHONPATH": os.pathsep.join(p for p in sys.path if p)}  # what this process imports
        try:
            # its own process group: a terminal's Ctrl-C reaches the session's process alone, which stops the loop
            # through the safe state (a stop request); the loop process never dies of it mid-cycle
            proc = launch.popen([sys.executable, "-m", "rehab_hil.loop.process", str(result_w)], stdin=subprocess.PIPE,
                                pass_fds=(self.hw.fd, result_w), env=env, process_group=0, warm=_warm(self.controller))
        finally:
            os.close(result_w)
        self.pid = proc.pid
        if self._stop is not None:  # a stop asked for while it started
            self.request_stop(*self._stop)
        pump = threading.Thread(target=self._pump, name="ring-reader", daemon=True)
        pump.start()
        try:
            _send(proc, job)
            return self._wait(proc, result_r, run)
        finally:
            self._done.set()
            pump.join()
            os.close(result_r)

    def _wait(self, proc: Child, result_r: int, run: dict[str, Any]) -> LoopReport:
        """The loop process's report, or, if it ended without one, the rig made safe from here."""
        data = _read_all(result_r, proc, START_TIMEOUT_S + run["duration_s"] + END_TIMEOUT_S)
        if proc.poll() is None and data:
            try:
                proc.wait(5.0)
            except subprocess.TimeoutExpired:
                pass
        try:
            got = pickle.loads(data)
        except Exception:  # nothing, or half a report: it died
            return _lost(proc, self.hw, self.dispatch, run)
        if got[0] == "unloadable":
            return self._here(got[1], run)
        report, link, controller = got
        self.hw.adopt_link_state(link)
        if hasattr(self.controller, "adopt"):
            self.controller.adopt(controller)
        self.overflow = getattr(report, "ring_overflow", 0)
        _device_said(self.hw, report)
        return report

    def _here(self, why: str, run: dict[str, Any]) -> LoopReport:
        """The loop process could not load its job: the loop runs in this process instead, said so."""
        self.pid = None
        self._done.set()
        service = LoopService(self.hw, self.configure, self.controller, self.estimator, self.supervisor,
                              self.period_s, self.dispatch)
        self.local_service = service
        if self._stop is not None:
            service.request_stop(*self._stop)
        report = service.run(**run)
        if report.realtime is not None:
            report.realtime = dataclasses.replace(report.realtime, process=f"the session's process (the loop "
                                                  f"process could not load its job: {why})")
        return report

    def _pump(self) -> None:
        """The ring reader: records to the dispatch until the loop process is done and the ring is read."""
        take, records = self.reader.take, self.dispatch.records
        while True:
            got = take()
            if got:
                records(got)
                continue
            if self._done.is_set():
                got = take()
                if not got:
                    return
                records(got)
            else:
                time.sleep(PUMP_IDLE_S)

    def reports(self) -> dict[str, dict[str, Any]]:
        """The ring's line in ``RunResult.sinks``: records the writer put over unread ones, and those the
        session's reader found gone."""
        return {"ring": {"dropped": self.reader.lost, "overflow": self.overflow, "error": None,
                         "holds_s": round(self.ring_s, 1)}}

    def close(self) -> None:
        self.ring.close()
        self.mailbox.close()


def _device_said(hw: Any, report: LoopReport) -> None:
    """A local simulated device's own stall counts, asked for here (this process holds its control
    channel), into the report's stall facts."""
    proc, facts = getattr(hw, "device_process", None), report.stall_facts
    if proc is not None and facts is not None and facts.simulated and proc.alive():
        facts.device_reported = proc.reported_stalls()


def _lost(proc: Child, hw: Any, dispatch: Dispatch, run: dict[str, Any]) -> LoopReport:
    """The loop process ended (or hung) without its report: ESTOP from this side, a safety event."""
    if proc.poll() is None:
        proc.kill()
    proc.wait()
    code = proc.returncode
    how = f"killed by signal {-code}" if code is not None and code < 0 else f"exit status {code}"
    detail = f"the loop process {proc.pid} ended without its report ({how})"
    try:
        hw.estop(timeout=0.5)
        hw.discard_pending()  # the samples from before the ESTOP
        detail += "; ESTOP sent from the session's process"
    except HardwareError as e:
        detail += f"; ESTOP not confirmed: {e}"
    figures = dispatch.figures
    t_s = float(figures.cols[0, figures.rows - 1]) if figures.rows else 0.0  # the last sample read
    event = SafetyEvent(t_s, "loop_process_lost", detail)
    dispatch.events([EventRecord(t_s, event.reason, detail)])
    return LoopReport(pacing=run.get("pacing", "device"), realtime=None, duration_s=run["duration_s"],
                      cycles=figures.commands, samples=figures.progress.samples, sample_gaps=0, reboots=0, timing={},
                      reaction={}, link=hw.stats.as_dict(), events=[event], final_sample=None,
                      stop_reason="safety trip: loop_process_lost", ran_s=t_s,
                      pwm_unconfirmed="the loop process ended: no sample after the trip was read")


def _warm(controller: Any) -> tuple[str, tuple[Any, ...]] | None:
    """What the zygote loads before it forks the loop process: the controller's engine (``launch.popen``)."""
    inner = getattr(controller, "controller", None)
    diagram, ctx = getattr(inner, "diagram", None), getattr(inner, "ctx", None)
    if diagram is None or ctx is None:
        return None
    return "rehab_hil.loop.controllers:load_engine", (diagram, ctx.period_s)


def _view(hw: Any) -> Any:
    """What the loop process needs of a local simulated device's process (None: a real board)."""
    proc = getattr(hw, "device_process", None)
    return proc.view() if proc is not None and hasattr(proc, "view") else None


def _send(proc: Child, job: LoopJob) -> None:
    """The job into the loop process's stdin (a process that died at its start: its exit is seen next)."""
    assert proc.stdin is not None
    try:
        proc.stdin.write(pickle.dumps(job, protocol=pickle.HIGHEST_PROTOCOL))
        proc.stdin.close()
    except (BrokenPipeError, OSError):
        pass


def _read_all(fd: int, proc: Child, timeout_s: float) -> bytes:
    """Everything the loop process writes to ``fd`` until it closes it (its end), or the timeout."""
    chunks, deadline = [], time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        ready, _, _ = select.select([fd], [], [], 0.2)
        if ready:
            chunk = os.read(fd, 1 << 20)
            if not chunk:
                break
            chunks.append(chunk)
        elif proc.poll() is not None and not select.select([fd], [], [], 0)[0]:
            break
    return b"".join(chunks)


if __name__ == "__main__":
    sys.exit(main())
