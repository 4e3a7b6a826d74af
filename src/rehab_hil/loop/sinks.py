"""The loop's sinks: one contract (``Sink``) and one base for sinks that work on a thread of their own
(``ThreadedSink``): the recorder, the zenoh publisher, the Foxglove feed and the live twin.

The loop offers each record (``loop.records``) to every sink right after its command is out and
then wakes each sink once; ``offer`` only appends to a bounded deque. What a full queue does is the
sink's one ``Overflow`` policy: ``DROP`` counts and drops the record (real time: the loop never
waits), ``WAIT`` holds the producer until there is room (a lockstep session, a zenoh recording:
back-pressure, not loss). An event record is never dropped for a full queue (events are few and
must not be lost; the cap bounds the sample flow).

The worker takes records (``handle``), calls ``tick`` every ``tick_s`` (flushing, stats) and
``finish`` once at the end. An exception in the worker is never silent: it is kept in ``error``,
``on_failure`` (set by the loop) is called once with one line naming the sink and the error, and
what was still queued and every later offer count as dropped.
"""

from __future__ import annotations

import enum
import threading
import time
from collections import deque
from collections.abc import Callable
from typing import Any, Protocol, runtime_checkable

from rehab_hil.loop.records import EventRecord

__all__ = ["Overflow", "Sink", "ThreadedSink", "sink_report"]

WAIT_POLL_S = 0.0005  # how often a producer held by a full WAIT queue looks again


class Overflow(enum.Enum):
    """What ``offer`` does when the queue is full."""

    DROP = "drop"  # count the record in ``dropped`` and return False (real time)
    WAIT = "wait"  # hold the producer until the worker made room (lockstep, zenoh recordings)


@runtime_checkable
class Sink(Protocol):
    """What the loop needs of a sink: ``offer`` (never blocks under ``DROP``) and ``wake`` from the
    loop thread; ``name``, ``critical``, ``dropped`` and ``error`` for the result; ``on_failure``,
    which the loop sets, called once if the sink stops working."""

    name: str
    critical: bool
    dropped: int
    error: BaseException | None
    on_failure: Callable[[str], None] | None

    def offer(self, record: Any) -> bool: ...

    def wake(self) -> None: ...

    def drain(self) -> None: ...

    def close(self) -> None: ...


def sink_report(sink: Sink) -> dict[str, Any]:
    """A sink's line in ``RunResult.sinks`` and ``metadata.json``: its drops and its error (or None)."""
    err = sink.error
    return {"dropped": int(sink.dropped), "error": None if err is None else f"{type(err).__name__}: {err}"}


class _CaughtUp(threading.Event):
    """A mark in a sink's queue, set when the worker reaches it (``ThreadedSink.catch_up``)."""


class ThreadedSink:
    """A bounded queue drained by a worker thread; subclasses implement ``handle`` (and may implement
    ``tick``, ``finish`` and ``release``). ``poll_s``: the longest the worker sleeps when nobody wakes
    it (a producer that never calls ``wake`` still gets its records handled); ``tick_s``: the period
    of ``tick`` (None: never)."""

    def __init__(self, name: str, queue_size: int, overflow: Overflow = Overflow.DROP, *, critical: bool = False,
                 poll_s: float = 0.05, tick_s: float | None = None) -> None:
        if queue_size < 1:
            raise ValueError(f"{name}: queue_size must be at least 1, got {queue_size}")
        self.name, self.critical, self.overflow = name, critical, overflow
        self.queue_size = queue_size
        self.poll_s, self.tick_s = poll_s, tick_s
        self.offered = 0
        self.dropped = 0
        self.error: BaseException | None = None
        self.on_failure: Callable[[str], None] | None = None
        self._q: deque[Any] = deque()  # appended by producers, taken by the worker
        self._cap = queue_size  # -1 once the worker failed or stopped: every offer takes the slow path
        self._kick = threading.Event()
        self._closing = False
        self._closed = False
        self._thread = threading.Thread(target=self._work, name=name, daemon=True)

    def start(self) -> None:
        """Start the worker (a subclass, once its own state is ready)."""
        self._thread.start()

    # -- producers (the loop thread; any thread) ----------------------------------------------------
    def offer(self, record: Any) -> bool:
        """Queue one record; on a full queue the overflow policy decides (False: dropped, counted)."""
        self.offered += 1
        q = self._q
        if len(q) >= self._cap:
            return self._full(record)
        q.append(record)
        return True

    def wake(self) -> None:
        """Let the worker take what is queued now (the loop: once per cycle, after its offers)."""
        self._kick.set()

    def _full(self, record: Any) -> bool:
        """The slow path of ``offer``: a full queue, or a worker that is no longer taking records."""
        if self._cap >= 0:
            if type(record) is EventRecord:
                self._q.append(record)  # events are few and never dropped for room
                return True
            if self.overflow is Overflow.WAIT:
                while len(self._q) >= self._cap >= 0:
                    self._kick.set()
                    time.sleep(WAIT_POLL_S)
                if self._cap >= 0:
                    self._q.append(record)
                    return True
        self.dropped += 1
        self.refused(record)
        return False

    def refused(self, record: Any) -> None:
        """Called for each record counted as dropped (a subclass's own counts); nothing by default."""

    # -- lifecycle ----------------------------------------------------------------------------------
    def drain(self, timeout_s: float | None = None) -> None:
        """Handle everything queued so far, ``finish``, and stop the worker (waiting at most
        ``timeout_s``); later offers are dropped (counted). Idempotent; at once after a failure."""
        if not self._closing:
            self._closing = True
            self._kick.set()
        if self._thread.is_alive():
            self._thread.join(timeout_s)
        self._cap = -1

    def close(self, timeout_s: float | None = None) -> None:
        """``drain``, then ``release`` what the sink holds (files, channels); idempotent."""
        if self._closed:
            return
        self._closed = True
        self.drain(timeout_s)
        self.release()

    def catch_up(self, timeout_s: float) -> bool:
        """Wait until every record offered before this call is handled (a lockstep session that must
        see what its twin made of the samples so far); False on a timeout or a stopped worker."""
        if self._cap < 0 or not self._thread.is_alive():
            return False
        mark = _CaughtUp()
        self._q.append(mark)
        self._kick.set()
        return mark.wait(timeout_s)

    @property
    def queued(self) -> int:
        """Records waiting for the worker."""
        return len(self._q)

    # -- the worker -----------------------------------------------------------------------------------
    def handle(self, record: Any) -> None:
        """One record, on the worker thread."""
        raise NotImplementedError

    def tick(self) -> None:
        """Every ``tick_s`` on the worker thread (flushing, stats)."""

    def finish(self) -> None:
        """Once, on the worker thread, after the last record (a final flush)."""

    def release(self) -> None:
        """Once, from ``close`` after the worker stopped (close files)."""

    def _work(self) -> None:
        try:
            self._loop()
        except BaseException as e:  # never silent: kept, reported once, later offers counted as dropped
            self._cap = -1
            self.error = e
            self.dropped += len(self._q)  # what was still queued is lost too
            self._q.clear()
            notify = self.on_failure
            if notify is not None:
                notify(f"{self.name}: {type(e).__name__}: {e}")

    def _loop(self) -> None:
        q, kick, tick_s = self._q, self._kick, self.tick_s
        next_tick = time.perf_counter() + tick_s if tick_s is not None else float("inf")
        while True:
            kick.wait(max(0.0, min(self.poll_s, next_tick - time.perf_counter())))
            kick.clear()
            closing = self._closing  # read before taking: whatever came before drain() is handled
            while q:
                record = q.popleft()
                if type(record) is _CaughtUp:
                    record.set()
                else:
                    self.handle(record)
            if closing:
                self.finish()
                return
            if tick_s is not None and time.perf_counter() >= next_tick:
                self.tick()
                next_tick = time.perf_counter() + tick_s
