"""Where the loop's records go once a command is out: the figures, the feeds and the sinks, in that order.

One ``Dispatch`` serves both ways a session runs: in lockstep the loop calls it itself after each write
(one process, nothing shared); while the loop runs in a process of its own, the session's process
reads the ring (``loop.ring``) and calls it with the same records. Each cycle's samples are taken
first (the rows, the meter), then its command (a finished cycle's ``CycleRecord``), then every record
is offered to every sink and each sink is woken once. A feed (the learning on the rig) takes each
command record synchronously: in lockstep its answer is in force before the next sample.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import Any

from rehab_hil.loop.figures import SessionFigures
from rehab_hil.loop.records import CommandRecord, EventRecord, SampleRecord
from rehab_hil.loop.sinks import Sink, sink_report

__all__ = ["Dispatch", "unique_names"]


class Dispatch:
    """The records' way after the write; see the module docstring."""

    def __init__(self, figures: SessionFigures, sinks: Sequence[Sink] = (),
                 feeds: Sequence[Callable[[CommandRecord], None]] = ()) -> None:
        self.figures = figures
        self.sinks = list(sinks)
        self.feeds = list(feeds)
        self._offers = [x.offer for x in self.sinks]
        self._wakes = [x.wake for x in self.sinks]

    def cycle(self, samples: Sequence[SampleRecord], command: CommandRecord | None) -> None:
        """One cycle's sample records (and its command's, None when the cycle ended before its write)."""
        figures, offers = self.figures, self._offers
        for rec in samples:
            figures.sample(rec)
        cycle = None
        if command is not None:
            cycle = figures.command(command)
            for feed in self.feeds:
                feed(command)
        if offers:
            for rec in samples:
                for offer in offers:
                    offer(rec)
            if command is not None:
                for offer in offers:
                    offer(command)
            if cycle is not None:
                for offer in offers:
                    offer(cycle)
            for wake in self._wakes:
                wake()

    def events(self, events: Sequence[EventRecord]) -> None:
        """Safety events, to the figures and every sink (recorded, published on zenoh's .../safety, shown)."""
        for rec in events:
            self.figures.event(rec)
            for offer in self._offers:
                offer(rec)
        for wake in self._wakes:
            wake()

    def records(self, records: Sequence[Any]) -> None:
        """Records read from the ring, in the loop's order: grouped into cycles at each command."""
        samples: list[SampleRecord] = []
        for rec in records:
            kind = type(rec)
            if kind is SampleRecord:
                samples.append(rec)
            elif kind is CommandRecord:
                self.cycle(samples, rec)
                samples = []
            else:
                if samples:
                    self.cycle(samples, None)
                    samples = []
                self.events([rec])
        if samples:
            self.cycle(samples, None)

    def reports(self) -> dict[str, dict[str, Any]]:
        """Each sink's drops and error, by unique name (``RunResult.sinks``)."""
        names = unique_names([x.name for x in self.sinks])
        return {n: sink_report(x) for n, x in zip(names, self.sinks, strict=True)}


def unique_names(names: list[str]) -> list[str]:
    """``names`` with a second "foxglove" as "foxglove-2" (keys of ``RunResult.sinks``)."""
    seen: dict[str, int] = {}
    out = []
    for n in names:
        seen[n] = seen.get(n, 0) + 1
        out.append(n if seen[n] == 1 else f"{n}-{seen[n]}")
    return out
