"""The loop's telemetry hook: a sink the loop offers records to without ever blocking.

``TelemetrySink`` is the minimal contract (offer, close) of a telemetry consumer; the loop's sinks
follow ``loop.sinks.Sink``. ``QueueSink`` hands records to a consumer callable on its own thread
(a ``ThreadedSink``: bounded queue, drops counted). ``loop_stats`` is the 1 Hz stats source.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any, Protocol, runtime_checkable

from rehab_hil.loop.sinks import ThreadedSink

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


class QueueSink(ThreadedSink):
    """Bounded queue + consumer thread: ``consume(record)`` runs off the loop thread."""

    def __init__(self, consume: Callable[[Any], None], maxsize: int = 1000, name: str = "telemetry") -> None:
        super().__init__(name, maxsize)
        self._consume = consume
        self.delivered = 0
        self.start()

    def handle(self, record: Any) -> None:
        self._consume(record)
        self.delivered += 1


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
