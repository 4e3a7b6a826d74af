"""The loop's sinks (``loop.sinks``): one bounded queue, one overflow policy, a worker whose
exception is never silent; and what a failed sink does to a session: a recorder that hits a full
disk stops it safely (PWM off, a ``sink_failure`` event naming it, what was written still
readable), a failed telemetry sink is reported and the session goes on to its duration."""

from __future__ import annotations

import errno
import os
import threading
import time

from rich.console import Console

from rehab_hil.cli.run import summary_table
from rehab_hil.interchange import read_csv
from rehab_hil.loop.recorder import Recorder, read_mcap
from rehab_hil.loop.records import CommandRecord, EventRecord
from rehab_hil.loop.run_dir import result_metadata
from rehab_hil.loop.sinks import Overflow, Sink, ThreadedSink
from rehab_hil.loop.stats import QueueSink
from rehab_hil.service.session import open_session

from .conftest import CONFIG


class Collect(ThreadedSink):
    """Keeps what it handles; ``gate`` holds the worker; ``fail_at``: raise on that record."""

    def __init__(self, queue_size: int, overflow: Overflow = Overflow.DROP, fail_at: int = -1, **kw) -> None:
        super().__init__("collect", queue_size, overflow, **kw)
        self.handled: list = []
        self.ticks = self.finished = 0
        self.gate = threading.Event()
        self.gate.set()
        self.fail_at = fail_at
        self.start()

    def handle(self, record) -> None:
        self.gate.wait()
        if len(self.handled) == self.fail_at:
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))
        self.handled.append(record)

    def tick(self) -> None:
        self.ticks += 1

    def finish(self) -> None:
        self.finished += 1


def test_drop_counts_what_a_full_queue_refuses_and_the_worker_takes_the_rest_in_order() -> None:
    sink = Collect(3, poll_s=60.0)  # nobody wakes it: the queue fills up
    accepted = [sink.offer(i) for i in range(10)]
    assert accepted == [True] * 3 + [False] * 7 and sink.dropped == 7 and sink.offered == 10
    assert sink.offer(EventRecord(0.1, "force", "41 N")) and sink.dropped == 7  # an event is never dropped for room
    sink.close()
    assert sink.handled == [0, 1, 2, EventRecord(0.1, "force", "41 N")] and sink.finished == 1
    assert not sink.offer(3) and sink.dropped == 8  # closed: counted, never queued
    sink.close()  # idempotent
    assert sink.error is None and isinstance(sink, Sink)


def test_wait_holds_the_producer_until_there_is_room_and_loses_nothing() -> None:
    sink = Collect(2, Overflow.WAIT, poll_s=0.001)
    sink.gate.clear()
    threading.Timer(0.05, sink.gate.set).start()  # the worker is stuck for a while
    t0 = time.perf_counter()
    assert all(sink.offer(i) for i in range(50))
    held_s = time.perf_counter() - t0
    sink.close()
    assert sink.handled == list(range(50)) and sink.dropped == 0 and held_s >= 0.04


def test_a_worker_exception_is_kept_reported_once_and_later_offers_count_as_dropped() -> None:
    told: list[str] = []
    sink = Collect(100, Overflow.WAIT, fail_at=2)
    sink.on_failure = told.append
    for i in range(5):
        sink.offer(i)
    sink.wake()
    deadline = time.monotonic() + 5.0
    while sink.error is None and time.monotonic() < deadline:
        time.sleep(0.005)
    assert isinstance(sink.error, OSError) and sink.handled == [0, 1]
    assert told == ["collect: OSError: [Errno 28] No space left on device"]
    dropped = sink.dropped
    assert not sink.offer(5) and sink.dropped == dropped + 1  # a failed WAIT sink never holds the producer
    sink.close()  # returns: nothing to wait for
    assert sink.finished == 0 and told == [told[0]]


def test_tick_runs_every_tick_s_while_records_flow() -> None:
    sink = Collect(100, poll_s=0.005, tick_s=0.01)
    for i in range(20):
        sink.offer(i)
        sink.wake()
        time.sleep(0.005)
    sink.close()
    assert sink.handled == list(range(20)) and sink.ticks >= 3


class DiskFillsUp(Recorder):
    """A recorder whose disk is full after ``flushes_ok`` flushes of rows: from then on its CSV file
    descriptor writes to /dev/full (ENOSPC), as a real full disk would answer."""

    def __init__(self, *args, flushes_ok: int, **kw) -> None:
        self.flushes_ok = flushes_ok
        super().__init__(*args, **kw)

    def _flush(self) -> None:
        if self._pending:
            if self.flushes_ok == 0:
                dev_full = os.open("/dev/full", os.O_WRONLY)
                os.dup2(dev_full, self._csv_fd)  # the CSV's descriptor now writes to a full disk
                os.close(dev_full)
            self.flushes_ok -= 1
        super()._flush()


def _session(sinks, duration_s: float = 3.0):
    with open_session(CONFIG, "inprocess", controller="pid", reference="step", sinks=tuple(sinks)) as session:
        return session, session.run(duration_s)


def test_a_recorder_on_a_full_disk_stops_the_session_safely_and_keeps_what_it_wrote(binding, tmp_path) -> None:
    rec = DiskFillsUp(tmp_path, binding, flush_s=0.02, flushes_ok=2)
    try:
        svc, res = _session([rec])
    finally:
        rec.close()
    assert res.pwm_off_at_end
    assert res.events[0].reason == "sink_failure" and res.stop_reason == "safety trip: sink_failure"
    assert res.events[0].detail == "recorder: OSError: [Errno 28] No space left on device"
    assert res.sinks == {"recorder": {"dropped": res.sinks["recorder"]["dropped"],
                                      "error": "OSError: [Errno 28] No space left on device"}}
    assert res.samples < 3000 and svc.sink_failures == [res.events[0].detail]  # stopped early
    rows = read_csv(tmp_path / "run.csv")["sample_index"].astype(int).tolist()
    assert len(rows) == rec.rows > 0 and rows == list(range(rows[0], rows[0] + len(rows)))  # whole lines, in order
    recorded = [m["sample_index"] for topic, _, m in read_mcap(tmp_path / "run.mcap") if topic == "/rig/sample"]
    assert recorded[:len(rows)] == rows


def test_a_failed_telemetry_sink_is_reported_and_the_session_runs_to_its_duration(binding, tmp_path) -> None:
    def publish(record) -> None:
        if type(record) is CommandRecord and record.command_seq == 200:
            raise ConnectionError("router gone")

    tel = QueueSink(publish, maxsize=20_000, name="telemetry")
    rec = Recorder(tmp_path, binding)
    try:
        svc, res = _session([rec, tel], duration_s=1.0)
    finally:
        rec.close()
        tel.close()
    assert not res.events and res.stop_reason == "duration reached" and res.pwm_off_at_end
    assert res.sinks["telemetry"]["error"] == "ConnectionError: router gone" and res.telemetry_dropped > 0
    assert res.sinks["recorder"] == {"dropped": 0, "error": None} and res.recorder_dropped == 0
    assert svc.sink_failures == ["telemetry: ConnectionError: router gone"]
    assert read_csv(tmp_path / "run.csv").t.size == res.samples
    assert result_metadata(res, rec.rows)["sinks"] == res.sinks  # metadata.json names each sink's drops and error
    console = Console(record=True, width=200)
    console.print(summary_table(res))
    text = console.export_text()
    assert "recorder drops" in text and "telemetry failed" in text and "ConnectionError: router gone" in text
