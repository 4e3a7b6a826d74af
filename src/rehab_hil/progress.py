"""Saying what a slow step does: a step that takes longer than ``AFTER_S`` (compiling the model,
learning a plan, the pre-flight run) names itself once it has taken that long, and says when it is
done; a quick one (a cache hit) says nothing.

The library is quiet until a front end gives a sink (``set_sink``: the CLI prints to standard
error). ``watch_compiles`` reports numba's compilations, which otherwise make the first session on a
clean cache a minute of silence.
"""

from __future__ import annotations

import json
import os
import threading
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from typing import Any

__all__ = ["AFTER_S", "announce", "set_sink", "watch_compiles"]

AFTER_S = 2.0  # a step quicker than this says nothing [s]

_sink: Callable[[str], None] | None = None


def set_sink(sink: Callable[[str], None] | None) -> None:
    """Where the lines go (None: nowhere, the default for library use)."""
    global _sink
    _sink = sink


@contextmanager
def announce(text: str, after_s: float = AFTER_S) -> Iterator[None]:
    """``text`` (what the block does) once the block has run ``after_s``, and its time when it ends."""
    if _sink is None:
        yield
        return
    sink = _sink
    t0 = time.monotonic()
    said = threading.Event()

    def say() -> None:
        said.set()
        sink(f"{text} ...")

    timer = threading.Timer(after_s, say)
    timer.daemon = True
    timer.start()
    try:
        yield
    finally:
        timer.cancel()
        if said.is_set():
            sink(f"{text}: done in {time.monotonic() - t0:.0f} s")


class _CompileDepth:
    """numba's ``numba:compile`` events (cache misses only: a cache hit raises none); the outermost
    compilation of a thread is announced, nested ones are part of it. With ``REHAB_HIL_COMPILE_LOG``
    set, each outermost compilation also appends a JSON line there (process, function, its file, start,
    wall and CPU seconds): ``bench/engine_census.py --log`` reads it to say what a run compiled, and what twice."""

    def __init__(self) -> None:
        self.depth = threading.local()
        self.blocks: dict[int, Any] = {}
        self.log = os.environ.get("REHAB_HIL_COMPILE_LOG")

    def on_start(self, event: Any) -> None:
        depth = getattr(self.depth, "n", 0)
        self.depth.n = depth + 1
        if depth == 0:
            block = announce("compiling the model (numba: once per model structure on this machine, then cached)")
            block.__enter__()
            self.blocks[threading.get_ident()] = block
            self.depth.started = (time.time(), time.perf_counter(), time.thread_time())

    def on_end(self, event: Any) -> None:
        depth = getattr(self.depth, "n", 0)
        self.depth.n = max(depth - 1, 0)
        if depth == 1 and (block := self.blocks.pop(threading.get_ident(), None)) is not None:
            block.__exit__(None, None, None)
            if self.log:
                self._write(event, *self.depth.started)

    def _write(self, event: Any, start: float, wall0: float, cpu0: float) -> None:
        py_func = event.data["dispatcher"].py_func
        line = {"pid": os.getpid(), "module": py_func.__module__, "function": py_func.__qualname__,
                "file": py_func.__code__.co_filename, "start": start, "wall_s": time.perf_counter() - wall0,
                "cpu_s": time.thread_time() - cpu0}
        with open(self.log, "a") as f:  # one short append per line: lines from parallel processes do not mix
            f.write(json.dumps(line) + "\n")


_watching = False


def watch_compiles() -> None:
    """Announce numba's compilations through ``announce`` (once per process; imports numba)."""
    global _watching
    if _watching:
        return
    from numba.core import event

    class Listener(_CompileDepth, event.Listener):
        pass

    event.register("numba:compile", Listener())
    _watching = True
