"""A session's result: the loop's own report, the figures of its records, its sinks, and what each of the
session's features contributed (``FeatureResult``: the twin, the learning on the rig, a kept assistance ...).

A feature's result is data with a name: its figures (``RunResult.feature(name)``), its keys of
``metadata.json`` (``metadata``), its lines of the run summary (``lines``) and the files it wrote. A new
capability adds a feature, not a field here.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from typing import Any

from rehab_hil.loop.runner import LoopReport
from rehab_hil.loop.trip_cause import StallFacts, explain
from rehab_hil.protocol import Status

__all__ = ["FeatureResult", "RunResult", "stall_figures"]


@dataclass(frozen=True)
class FeatureResult:
    """What one session feature contributes: ``figures`` (what ``RunResult.feature`` returns), ``metadata``
    (its top-level keys of metadata.json), ``lines`` (label, text) for the run summary, and its files."""

    name: str
    figures: dict[str, Any] = field(default_factory=dict)
    metadata: dict[str, Any] = field(default_factory=dict)
    lines: tuple[tuple[str, str], ...] = ()
    files: tuple[str, ...] = ()


@dataclass
class RunResult(LoopReport):
    """Everything the summary prints: the loop's report (``LoopReport``) and the session's figures."""

    tracking: dict[str, float] = field(default_factory=dict)  # run.csv's rows (metrics.recorded_tracking)
    session: dict[str, float] = field(default_factory=dict)  # per-cycle figures summed up (session_metrics)
    session_cycles: list[dict[str, Any]] = field(default_factory=list)
    step: dict[str, float] = field(default_factory=dict)  # a step run's response (metrics.recorded_step)
    sinks: dict[str, dict[str, Any]] = field(default_factory=dict)  # name -> {"dropped": n, "error": str | None}
    files: list[str] = field(default_factory=list)
    # the stalls seen: the host's write gap at the trip, the device's silences while its process could
    # not run (host view) and the stalls it reported itself (loop/trip_cause.py)
    stalls: dict[str, Any] = field(default_factory=dict)
    features: dict[str, FeatureResult] = field(default_factory=dict)

    @classmethod
    def of(cls, report: LoopReport, **figures: Any) -> RunResult:
        """The session's result from the loop's report: each trip's cause explained from its stall facts."""
        core = {f.name: getattr(report, f.name) for f in dataclasses.fields(LoopReport)}
        facts = report.stall_facts
        if facts is not None:
            core["events"] = [dataclasses.replace(e, cause=explain(e, facts)) for e in report.events]
            figures.setdefault("stalls", stall_figures(facts, bool(report.events)))
        return cls(**core, **figures)

    def feature(self, name: str) -> dict[str, Any]:
        """A feature's figures ({} when the session did not have it)."""
        got = self.features.get(name)
        return got.figures if got is not None else {}

    @property
    def twin(self) -> dict[str, Any]:
        return self.feature("twin")

    @property
    def learning(self) -> dict[str, Any]:
        return self.feature("rig_learning")

    @property
    def assistance(self) -> dict[str, Any]:
        return self.feature("assistance")

    @property
    def recorder_dropped(self) -> int:
        return int(self.sinks.get("recorder", {}).get("dropped", 0))

    @property
    def telemetry_dropped(self) -> int:
        """Drops of the live views: zenoh telemetry and the Foxglove feed."""
        return sum(int(v["dropped"]) for k, v in self.sinks.items() if k in ("telemetry", "foxglove"))

    @property
    def twin_dropped(self) -> int:
        return int(self.sinks.get("twin", {}).get("dropped", 0))

    @property
    def pwm_off_at_end(self) -> bool | None:
        """The last sample shows every PWM off; None when no sample after the trip could show it
        (``pwm_unconfirmed`` says why)."""
        if self.pwm_unconfirmed:
            return None
        s = self.final_sample
        return s is not None and s.duty0 == 0 and s.duty1 == 0 and not (s.status & Status.PWM_ENABLED)


def stall_figures(facts: StallFacts, tripped: bool) -> dict[str, Any]:
    """The stalls part of the result and metadata.json."""
    return {"host_gap_at_trip_ms": facts.host_gap_s * 1e3 if tripped else None,
            "host_cpu_wait_at_trip_ms": facts.host_cpu_wait_s * 1e3 if tripped else None,
            "device_silences_not_scheduled": [dataclasses.asdict(x) for x in facts.device_stalls],
            "device_reported": facts.device_reported}
