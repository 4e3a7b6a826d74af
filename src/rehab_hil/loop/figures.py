"""The session's figures from the loop's records, as the recorder writes them, wherever the records are read.

``SessionFigures`` takes each sample's record and each command's (in the loop's thread in lockstep, or
from the ring in the session's process while the loop runs in its own): every recorded row's time,
reference and angle (the summary's tracking figures are run.csv's), the per-cycle meter
(``session_metrics.SessionMeter``: a ``CycleRecord`` per finished open-close cycle) and the live
``Progress`` a display reads.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from rehab_hil import metrics
from rehab_hil.loop.records import CommandRecord, CycleRecord, EventRecord, SampleRecord
from rehab_hil.session_metrics import SessionMeter

__all__ = ["PROGRESS_EVERY", "Progress", "SessionFigures"]

PROGRESS_EVERY = 50  # commands between updates of the live figures


@dataclass
class Progress:
    """Live figures the display thread reads (plain floats; written by whoever reads the records)."""

    t_s: float = 0.0
    duration_s: float = 0.0
    angle_deg: float = math.nan
    reference_deg: float = math.nan
    duty: float = 0.0
    temperature_c: float = math.nan
    samples: int = 0
    sample_gaps: int = 0  # samples missing from the device's sample_index sequence
    tripped: str = ""
    last_cycle: dict[str, float] = field(default_factory=dict)  # the last finished open-close cycle's figures


class SessionFigures:
    """Rows, per-cycle figures and progress from the records; see the module docstring. ``effort_of``:
    the effort a command applies (the controller's actuator), for the meter's energy."""

    def __init__(self, capacity: int, duration_s: float, meter: SessionMeter | None = None,
                 effort_of: Callable[[Any], float] | None = None) -> None:
        self.meter = meter
        self.effort_of = effort_of or (lambda cmd: math.nan)
        self.progress = Progress(duration_s=duration_s)
        self.rows = 0
        self.cols = np.full((3, capacity), np.nan)  # time, reference (of the command in force), angle
        self.commands = 0
        self._first_index: int | None = None
        self._last_index: int | None = None
        self._angle = math.nan

    def sample(self, rec: SampleRecord) -> None:
        """One recorded row: its time, the reference of the command in force, the sample's angle."""
        st, cmd = rec.state, rec.command
        angle = st.angle_deg if st is not None else math.nan
        n = self.rows
        if n < self.cols.shape[1]:
            c = self.cols
            c[0, n], c[1, n], c[2, n] = rec.time_s, cmd.reference_deg, angle
            self.rows = n + 1
        meter = self.meter
        if meter is not None and st is not None:
            meter.add(rec.time_s, cmd.reference_deg, angle, self.effort_of(cmd), st.velocity_rad_s,
                      rec.temperature_c, meter.torque_of(st.analog))
        self.progress.samples += 1
        self._last_index = rec.sample.sample_index
        if self._first_index is None:
            self._first_index = self._last_index
        self._angle = angle

    def command(self, rec: CommandRecord) -> CycleRecord | None:
        """One command: the live figures every ``PROGRESS_EVERY``, and a finished cycle's record."""
        self.commands += 1
        if self.commands % PROGRESS_EVERY == 0:
            p, cmd = self.progress, rec.command
            p.t_s, p.angle_deg, p.reference_deg = rec.time_s, self._angle, cmd.reference_deg
            p.duty, p.temperature_c = max(cmd.duty), rec.temperature_c
            if self._first_index is not None and self._last_index is not None:  # indices missing so far (a
                span = (self._last_index - self._first_index) & 0xFFFFFFFF  # restart makes it 0 for a while)
                p.sample_gaps = max(0, span + 1 - p.samples) if span < 0x80000000 else p.sample_gaps
        if self.meter is None:
            return None
        cycle = self.meter.poll()
        if cycle is None:
            return None
        self.progress.last_cycle = cycle.as_dict()
        return CycleRecord(cycle.as_dict())

    def event(self, rec: EventRecord) -> None:
        if not self.progress.tripped:
            self.progress.tripped = rec.kind

    def recorded_rows(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(time, reference, angle) of the rows taken so far (the recording's rows, in order)."""
        t, r, a = self.cols[:, :self.rows]
        return t, r, a

    def tracking(self) -> dict[str, float]:
        _, refs, angles = self.recorded_rows()
        return metrics.recorded_tracking(refs, angles)

    def session(self) -> tuple[dict[str, float], list[dict[str, float]]]:
        """The session's per-cycle figures summed up, and each cycle's ({} and [] without a meter)."""
        if self.meter is None:
            return {}, []
        return self.meter.summary(), [c.as_dict() for c in self.meter.cycles]
