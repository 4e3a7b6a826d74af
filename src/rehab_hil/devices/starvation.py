"""The host's view of a local simulated device's stall: was its process able to run?

A silence on the link is a lost link only if the device could have spoken. ``Starvation`` reads,
for the spawned device process and its children (the avr harness, a USB-bridge model), the time
each waited on a run queue (``/proc/PID/schedstat``, second field) and whether it is stopped
(``/proc/PID/stat`` state T); ``poll()`` returns how much of the wall time since ``start()`` the
device could not run (the most starved of its processes: the chain stops with any of them). A
process that is gone or asleep is not starved: its silence is the link's.
"""

from __future__ import annotations

import time
from pathlib import Path

__all__ = ["Starvation"]

PROC = Path("/proc")


def process_tree(pid: int) -> list[int]:
    """``pid`` and its descendants (via /proc/PID/task/*/children)."""
    out, todo = [], [pid]
    while todo:
        p = todo.pop()
        out.append(p)
        try:
            for task in (PROC / str(p) / "task").iterdir():
                todo += [int(c) for c in (task / "children").read_text().split()]
        except (OSError, ValueError):
            continue
    return out


def _read(pid: int) -> tuple[int, bool] | None:
    """(run-queue wait [ns], stopped) of ``pid``'s main thread, or None if it is gone."""
    try:
        wait_ns = int((PROC / str(pid) / "schedstat").read_text().split()[1])
        stat = (PROC / str(pid) / "stat").read_text()
    except (OSError, ValueError, IndexError):
        return None
    state = stat[stat.rindex(")") + 2]
    if state in "ZX":
        return None
    return wait_ns, state in "Tt"


class Starvation:
    """Starvation of one device process tree over a window (see the module docstring)."""

    def __init__(self, pid: int) -> None:
        self.pid = pid
        self.starved_s = 0.0
        self._last: dict[int, tuple[int, bool]] = {}
        self._t = 0.0

    def alive(self) -> bool:
        return _read(self.pid) is not None

    def start(self) -> None:
        """A new window (a silence began): the baseline, nothing starved yet."""
        self._t = time.perf_counter()
        self._last = {p: r for p in process_tree(self.pid) if (r := _read(p)) is not None}
        self.starved_s = 0.0

    def poll(self) -> float:
        """The seconds of the window the device could not run, up to now."""
        now = time.perf_counter()
        dt, self._t = now - self._t, now
        worst = 0.0
        current: dict[int, tuple[int, bool]] = {}
        for p in process_tree(self.pid):
            r = _read(p)
            if r is None:
                continue
            current[p] = r
            before = self._last.get(p)
            waited = (r[0] - before[0]) * 1e-9 if before is not None else 0.0
            worst = max(worst, dt if r[1] else min(waited, dt))
        self._last = current
        self.starved_s += worst
        return self.starved_s
