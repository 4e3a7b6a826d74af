"""What the loop hands its sinks (recorder, telemetry, Foxglove, twin): one typed record per kind.

Named tuples, because the loop builds one per sample at 1 kHz between a command going out and the
next sample coming in (a tuple is built in a fraction of a frozen dataclass's time). A sink
dispatches on the type (``type(r) is SampleRecord``, or ``match``): a command is a
``CommandRecord``, never a sample record without a sample.
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING, Any, NamedTuple

if TYPE_CHECKING:  # annotations only: the telemetry codec imports this module without the service's weight
    from rehab_hil.loop.controllers import Command
    from rehab_hil.loop.estimation import State
    from rehab_hil.protocol import Sample

__all__ = ["CommandRecord", "CycleRecord", "EventRecord", "LoopRecord", "MessageRecord", "SampleRecord"]


class SampleRecord(NamedTuple):
    """A sample the loop took: its estimate and the command in force when it arrived."""

    host_time_s: float  # arrival on the host's perf_counter clock
    time_s: float  # position on the recording's time axis (continued sample index x period)
    sample: Sample
    state: State | None
    command: Command
    command_seq: int
    temperature_c: float


class CommandRecord(NamedTuple):
    """A command the loop wrote, with what its controller computed for it: the row of its periodic table
    it read, its tracking error, the effort it asked for and the demand its limit did not apply (the
    learning on the rig learns from these; -1, nan and 0 for a controller without them)."""

    host_time_s: float  # when it was out (perf_counter)
    time_s: float  # the time of the sample it answered
    command: Command
    command_seq: int
    temperature_c: float
    row: int = -1  # the plan row read (-1: no periodic table)
    error_deg: float = math.nan  # reference - angle the controller saw [deg]
    effort: float = math.nan  # the effort asked for, after the controller's own limits [actuator unit]
    saturation: float = 0.0  # the demand the limit cut [actuator unit]


class CycleRecord(NamedTuple):
    """One finished open-close cycle's figures (``session_metrics.CycleMetrics.as_dict``)."""

    metrics: dict[str, float]


class EventRecord(NamedTuple):
    """A safety, link or model event (``kind``: a supervisor reason, "model_mismatch", ...)."""

    time_s: float
    kind: str
    detail: str = ""


class MessageRecord(NamedTuple):
    """One message on an extra channel (the live twin's ``/twin/prediction``): the recording's topic,
    its schema's name and a flat JSON body."""

    topic: str
    schema: str
    body: dict[str, Any]


LoopRecord = SampleRecord | CommandRecord | CycleRecord | EventRecord | MessageRecord
