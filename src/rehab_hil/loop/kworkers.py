"""The kernel's tty workers raised above the machine's ordinary work while a real-time session runs.

Bytes on a serial link do not reach the reader when the writer writes them: the tty layer hands each
chunk to a kernel worker (``flush_to_ldisc`` on the unbound workqueue, threads named ``kworker/u*``)
that runs as an ordinary SCHED_OTHER thread. Beside two busy loops such a worker waits for a CPU, and a
SCHED_FIFO loop waiting in ``poll`` for a sample waits with it: priority inversion in the kernel. A
FIFO loop and a FIFO simulated device over a pty, with load 13 of ordinary processes beside them, saw
gaps of up to 299 ms between samples; with the unbound workers at SCHED_FIFO 1, none over 20 ms in 40 s
(docs/loop.md, "The kernel's tty workers"). A real board's USB serial (cdc_acm) goes the same way.

``KworkerBoost`` raises every ``kworker/u*`` thread that runs SCHED_OTHER to SCHED_FIFO ``priority``
(below the simulated device's 5 and the loop's 10), again every ``every_s`` (the pool makes new workers),
and puts back what it changed at the end unless another loop process still runs. Needs root or
CAP_SYS_NICE; without it the session says so and runs as before.
"""

from __future__ import annotations

import os
import threading
from pathlib import Path

__all__ = ["KworkerBoost", "unbound_workers"]

PRIORITY = 1
EVERY_S = 1.0
PROC = Path("/proc")


def unbound_workers() -> list[int]:
    """The pids of the kernel's unbound workqueue threads (``kworker/u*``)."""
    out = []
    for d in PROC.iterdir():
        if not d.name.isdigit():
            continue
        try:
            if (d / "comm").read_text().startswith("kworker/u"):
                out.append(int(d.name))
        except OSError:
            continue
    return out


class KworkerBoost:
    """See the module docstring; ``start``/``stop`` around a real-time session, ``note`` says what it did."""

    def __init__(self, priority: int = PRIORITY, every_s: float = EVERY_S) -> None:
        self.priority, self.every_s = priority, every_s
        self.changed: dict[int, int] = {}  # pid -> the nice value it had (SCHED_OTHER before)
        self.refused = ""
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None

    def raise_now(self) -> int:
        """Raise the unbound workers running SCHED_OTHER; returns how many it changed this time."""
        n = 0
        for pid in unbound_workers():
            try:
                if os.sched_getscheduler(pid) != os.SCHED_OTHER:
                    continue
                nice = os.getpriority(os.PRIO_PROCESS, pid)
                os.sched_setscheduler(pid, os.SCHED_FIFO, os.sched_param(self.priority))
            except PermissionError as e:
                self.refused = f"not permitted ({e.strerror}): the tty workers stay SCHED_OTHER"
                return n
            except OSError:  # gone meanwhile
                continue
            self.changed.setdefault(pid, nice)
            n += 1
        return n

    def start(self) -> KworkerBoost:
        self.raise_now()
        if not self.refused:
            self._thread = threading.Thread(target=self._again, name="kworker-boost", daemon=True)
            self._thread.start()
        return self

    def _again(self) -> None:
        while not self._stop.wait(self.every_s):
            self.raise_now()

    def stop(self, others_running: bool = False) -> None:
        """Stop raising; put back the workers it changed, unless ``others_running`` (another session's
        loop still needs them raised)."""
        self._stop.set()
        if self._thread is not None:
            self._thread.join(2.0)
        if others_running:
            return
        for pid, nice in self.changed.items():
            try:
                if os.sched_getscheduler(pid) == os.SCHED_FIFO:
                    os.sched_setscheduler(pid, os.SCHED_OTHER, os.sched_param(0))
                    os.setpriority(os.PRIO_PROCESS, pid, nice)
            except OSError:
                continue

    @property
    def note(self) -> str:
        if self.refused:
            return self.refused
        raised = 0
        for pid in unbound_workers():
            try:
                raised += os.sched_getscheduler(pid) == os.SCHED_FIFO
            except OSError:
                continue
        return (f"{raised} kernel tty workers (kworker/u*) at SCHED_FIFO {self.priority} ({len(self.changed)} "
                "raised by this session)")


def loop_processes_running(but: int | None = None) -> bool:
    """Whether a loop process (``rehab_hil.loop.process``) other than ``but`` runs on this machine."""
    for d in PROC.iterdir():
        if not d.name.isdigit() or int(d.name) == but:
            continue
        try:
            if b"rehab_hil.loop.process" in (d / "cmdline").read_bytes():
                return True
        except OSError:
            continue
    return False
