"""Fixed-rate loop timing: absolute deadlines on a monotonic clock, sleep then spin, no catch-up.

A cycle's lateness is its wake time minus its deadline. A cycle whose deadline has already passed
by a whole period is skipped and counted as missed (the loop never runs a burst of late cycles to
catch up). ``realtime_setup`` freezes the garbage collector, shortens the interpreter's switch
interval (a thread waiting for the GIL asks for it after this long: the loop, woken by a sample
while the recorder or the publisher holds the GIL, waits at most about that) and asks for
SCHED_FIFO, and reports what it got. Figures and the reasoning behind them: docs/loop.md.
"""

from __future__ import annotations

import gc
import os
import sys
import threading
import time
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass

import numpy as np

__all__ = ["SPIN_S", "DeadlineTimer", "RealtimeReport", "TimingStats", "lock_memory", "realtime_setup",
           "realtime_teardown", "run_queue_wait_s", "threads_niced"]

SPIN_S = 200e-6  # sleep until this long before the deadline, then spin (sleep overshoots ~60-100 us)
SWITCH_INTERVAL_S = 50e-6  # the GIL switch interval while the loop runs (CPython's default: 5 ms)
_saved_switch_interval: list[float] = []
# The loop shares the GIL with its process's other threads (the main thread, the sinks' workers): one
# descheduled while it holds the GIL stops the loop however high its priority (a host stall of 60-590
# ms beside busy loops, the loop thread blocked, not waiting for a CPU: bench/busy_sessions.py). At
# nice -20 a busy SCHED_OTHER process (nice 0) barely delays them, and unlike SCHED_FIFO a heavy
# helper (a fit) cannot take a core from everything else. Tried: SCHED_FIFO 1 for them did worse on
# the same bench (3 of 4 sessions host stalls, one link loss; more real-time load on 2 cores)
# (docs/loop.md, 'Scheduling').
HELPER_NICE = -20
_saved_nice: list[tuple[int, int]] = []  # (thread id, nice value before realtime_setup)


@dataclass(frozen=True)
class RealtimeReport:
    """What ``realtime_setup`` obtained: the scheduler and whether the GC was frozen."""

    scheduler: str  # "SCHED_FIFO <prio>" or "SCHED_OTHER (<why>)"
    gc_frozen: bool
    switch_interval_s: float = SWITCH_INTERVAL_S
    process: str = ""  # a loop process's pid, its memory lock and its threads ("": the session's own process)
    tty_workers: str = ""  # the kernel's tty workers raised for the session (loop/kworkers.py), or why not


def realtime_setup(fifo_priority: int | None = 10, switch_interval_s: float = SWITCH_INTERVAL_S,
                   helper_nice: int | None = None) -> RealtimeReport:
    """Collect and freeze the GC (a full collection costs 1.5-16 ms), set the GIL switch interval
    and request SCHED_FIFO (for the calling thread: the loop's); ``helper_nice``: the nice value of
    the process's other threads meanwhile (``HELPER_NICE`` for the host loop; None: left alone).

    SCHED_FIFO needs root or CAP_SYS_NICE; without it the loop runs SCHED_OTHER and says so.
    ``fifo_priority=None`` skips the request. Call ``realtime_teardown`` afterwards."""
    if helper_nice is not None:
        _renice_other_threads(helper_nice)
    gc.collect()
    gc.freeze()
    _saved_switch_interval.append(sys.getswitchinterval())
    sys.setswitchinterval(switch_interval_s)
    if fifo_priority is None:
        return RealtimeReport("SCHED_OTHER (not requested)", True, switch_interval_s)
    try:
        os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(fifo_priority))
    except (PermissionError, OSError, AttributeError) as e:
        return RealtimeReport(f"SCHED_OTHER ({type(e).__name__}: SCHED_FIFO not permitted)", True,
                              switch_interval_s)
    return RealtimeReport(f"SCHED_FIFO {fifo_priority}", True, switch_interval_s)


def lock_memory() -> str:
    """Lock the process's pages in RAM, present and future (``mlockall``): a loop process never waits
    for a page to come back from swap. Says what it got (needs CAP_IPC_LOCK or a large enough
    RLIMIT_MEMLOCK)."""
    import ctypes
    import ctypes.util

    mcl_current, mcl_future = 1, 2
    try:
        libc = ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6", use_errno=True)
        if libc.mlockall(mcl_current | mcl_future) != 0:
            return f"not locked ({os.strerror(ctypes.get_errno())})"
    except (OSError, AttributeError) as e:
        return f"not locked ({type(e).__name__})"
    return "locked"


@contextmanager
def threads_niced(nice: int) -> Iterator[int]:
    """Every thread of this process at ``nice`` meanwhile (threads started meanwhile inherit it from the
    thread that starts them), then back: the session's process while its loop runs in a process of its
    own, so the ring's reader, the recorder and zenoh keep up beside busy ordinary processes. Yields how
    many threads it changed (0 without CAP_SYS_NICE)."""
    saved = []
    for tid in _task_ids():
        try:
            old = os.getpriority(os.PRIO_PROCESS, tid)
            os.setpriority(os.PRIO_PROCESS, tid, nice)
            saved.append((tid, old))
        except OSError:  # gone meanwhile, or not permitted
            continue
    try:
        yield len(saved)
    finally:
        for tid, old in saved:
            try:
                os.setpriority(os.PRIO_PROCESS, tid, old)
            except OSError:
                continue
        me = threading.get_native_id()
        for tid in _task_ids():  # threads started meanwhile took the raised value: back to the caller's
            if tid != me and not any(t == tid for t, _ in saved):
                try:
                    os.setpriority(os.PRIO_PROCESS, tid, os.getpriority(os.PRIO_PROCESS, me))
                except OSError:
                    continue


def _task_ids() -> list[int]:
    try:
        return [int(t) for t in os.listdir("/proc/self/task")]
    except OSError:
        return []


def _renice_other_threads(nice: int) -> None:
    """Every thread of this process but the caller to ``nice`` (saved for ``realtime_teardown``)."""
    me = threading.get_native_id()
    try:
        tids = [int(t) for t in os.listdir("/proc/self/task")]
    except OSError:
        return
    for tid in tids:
        if tid == me:
            continue
        try:
            old = os.getpriority(os.PRIO_PROCESS, tid)
            os.setpriority(os.PRIO_PROCESS, tid, nice)
        except OSError:  # gone meanwhile, or not permitted (no CAP_SYS_NICE): left as it is
            continue
        _saved_nice.append((tid, old))


def run_queue_wait_s() -> float:
    """The calling thread's time spent runnable but waiting for a CPU so far (/proc schedstat);
    0.0 where the kernel does not say. Its growth over a stall tells "not scheduled" from "blocked"."""
    try:
        with open("/proc/thread-self/schedstat") as f:
            return int(f.read().split()[1]) * 1e-9
    except (OSError, ValueError, IndexError):
        return 0.0


def realtime_teardown() -> None:
    """Back to SCHED_OTHER, the switch interval it had and a normal GC (the recorder and the
    summary allocate freely)."""
    try:
        if os.sched_getscheduler(0) == os.SCHED_FIFO:
            os.sched_setscheduler(0, os.SCHED_OTHER, os.sched_param(0))
    except (PermissionError, OSError, AttributeError):
        pass
    while _saved_nice:
        tid, old = _saved_nice.pop()
        try:
            os.setpriority(os.PRIO_PROCESS, tid, old)
        except OSError:
            continue
    if _saved_switch_interval:
        sys.setswitchinterval(_saved_switch_interval.pop())
    gc.unfreeze()


class TimingStats:
    """Lateness of every executed cycle (preallocated, no allocation per cycle) and missed cycles."""

    def __init__(self, capacity: int) -> None:
        self._late = np.zeros(max(1, capacity))
        self.n = 0
        self.missed = 0
        self.overflow = 0

    def add(self, lateness_s: float) -> None:
        if self.n < self._late.size:
            self._late[self.n] = lateness_s
            self.n += 1
        else:
            self.overflow += 1

    @property
    def lateness_s(self) -> np.ndarray:
        return self._late[: self.n]

    def summary(self) -> dict[str, float]:
        """Lateness percentiles in microseconds, executed and missed cycles, missed share in %."""
        late = self.lateness_s * 1e6
        total = self.n + self.overflow + self.missed
        pct = (lambda q: float(np.percentile(late, q))) if late.size else (lambda q: float("nan"))
        return {
            "cycles": float(self.n + self.overflow),
            "missed_cycles": float(self.missed),
            "missed_pct": 100.0 * self.missed / total if total else 0.0,
            "lateness_p50_us": pct(50),
            "lateness_p99_us": pct(99),
            "lateness_p99_9_us": pct(99.9),
            "lateness_max_us": float(late.max()) if late.size else float("nan"),
        }


class DeadlineTimer:
    """Wakes at t0 + k * period on ``time.perf_counter`` (CLOCK_MONOTONIC based).

    ``wait()`` sleeps until ``SPIN_S`` before the next deadline, spins to it, records the lateness,
    and returns the index k of the cycle it woke for. Deadlines already passed are skipped and
    counted in ``stats.missed`` (never caught up)."""

    def __init__(self, period_s: float, capacity: int, spin_s: float = SPIN_S) -> None:
        if not period_s > 0:
            raise ValueError(f"period must be positive, got {period_s}")
        self.period_s = float(period_s)
        self.spin_s = float(spin_s)
        self.stats = TimingStats(capacity)
        self.t0 = 0.0
        self.k = -1

    def start(self, t0: float | None = None) -> None:
        """Anchor the deadlines: cycle 0 is due at ``t0`` (default: now)."""
        self.t0 = time.perf_counter() if t0 is None else t0
        self.k = -1

    def wait(self) -> int:
        k = self.k + 1
        now = time.perf_counter()
        deadline = self.t0 + k * self.period_s
        if now - deadline >= self.period_s:  # overran: skip every deadline already gone
            skipped = int((now - deadline) // self.period_s)
            self.stats.missed += skipped
            k += skipped
            deadline = self.t0 + k * self.period_s
        remaining = deadline - now
        if remaining > self.spin_s:
            time.sleep(remaining - self.spin_s)
        now = time.perf_counter()
        while now < deadline:
            now = time.perf_counter()
        self.stats.add(now - deadline)
        self.k = k
        return k

    def deadline(self, k: int) -> float:
        return self.t0 + k * self.period_s
