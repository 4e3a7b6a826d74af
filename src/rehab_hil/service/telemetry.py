"""The loop's telemetry hook: a sink the loop offers samples to without ever blocking.

``TelemetrySink`` is the whole contract (the zenoh publisher, ``rehab_hil.telemetry``, is one); the
loop offers after its command is out. ``QueueSink`` hands
samples to a consumer callable on its own thread through a bounded queue and counts drops.
"""

from __future__ import annotations

import queue
import threading
from collections.abc import Callable
from typing import Any, Protocol, runtime_checkable

__all__ = ["NullSink", "QueueSink", "TelemetrySink", "loop_stats"]


@runtime_checkable
class TelemetrySink(Protocol):
    def offer(self, sample: Any) -> bool:
        """Take one sample if there is room; never block. False when it was dropped."""
        ...

    # optional: ``wake()``, which the loop calls once per cycle after its write (and after its
    # offers) so that a worker thread takes the records while the loop waits for its next sample

    def close(self) -> None: ...


class NullSink:
    """The default: telemetry off."""

    dropped = 0

    def offer(self, sample: Any) -> bool:
        return True

    def close(self) -> None:
        pass


class QueueSink:
    """Bounded queue + consumer thread: ``consume(sample)`` runs off the loop thread."""

    def __init__(self, consume: Callable[[Any], None], maxsize: int = 1000) -> None:
        self._consume = consume
        self._q: queue.Queue[Any] = queue.Queue(maxsize=maxsize)
        self.dropped = 0
        self.delivered = 0
        self._stop = object()
        self._thread = threading.Thread(target=self._run, name="telemetry", daemon=True)
        self._thread.start()

    def offer(self, sample: Any) -> bool:
        try:
            self._q.put_nowait(sample)
            return True
        except queue.Full:
            self.dropped += 1
            return False

    def _run(self) -> None:
        while True:
            item = self._q.get()
            if item is self._stop:
                return
            self._consume(item)
            self.delivered += 1

    def close(self) -> None:
        """Deliver what is queued, then stop the thread; idempotent."""
        if self._thread.is_alive():
            self._q.put(self._stop)
            self._thread.join()


def loop_stats(service: Any, hw: Any) -> Callable[[], dict[str, Any]]:
    """The 1 Hz stats message's source: loop progress and the link figures (zenoh and Foxglove)."""

    def stats() -> dict[str, Any]:
        p = service.progress
        out: dict[str, Any] = {k: getattr(p, k) for k in ("t_s", "duration_s", "samples", "sample_gaps", "tripped")}
        if getattr(p, "last_cycle", None):
            out["cycle"] = p.last_cycle  # the last finished open-close cycle (session_metrics)
        link = getattr(hw, "stats", None)
        if link is not None:
            d = link.as_dict()
            d["bad_frames"] = sum(d["bad_frames"].values())
            out["link"] = d
        return out

    return stats
