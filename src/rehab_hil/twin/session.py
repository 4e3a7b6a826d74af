"""The live twin in a ``rehab-hil run``: built from the config, wired to the recording, zenoh and
Foxglove, diagnosing on a worker thread, and summed up for ``metadata.json`` and the summary."""

from __future__ import annotations

import threading
import time
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

from rehab_hil.config import TwinSection
from rehab_hil.interfaces import DeviceBinding
from rehab_hil.plants.registry import get_plant
from rehab_hil.twin.live import LiveTwin, Twin
from rehab_hil.twin.model import TwinSetupError
from rehab_hil.twin.monitor import MismatchEvent
from rehab_hil.twin.outputs import SinkOutput, ZenohOutput
from rehab_hil.twin.thermal import ThermalEvent

__all__ = ["TwinRun", "start_twin"]

MIN_WINDOW_S = 1.0  # a mismatch the session ended on is diagnosed on what there is, if at least this long [s]
DIAGNOSIS_WAIT_S = 20.0  # at the session's end, how long a running diagnosis is waited for


class TwinRun:
    """A running twin and its diagnoses; ``close`` finishes both and gives the metadata."""

    def __init__(self, live: LiveTwin, cfg: Any, cycle_s: float | None = None) -> None:
        self.live, self.cfg, self.cycle_s = live, cfg, cycle_s
        self.twin = live.twin
        self._threads: list[threading.Thread] = []
        self.on_stop: Callable[[str], None] | None = None
        # the hook a controller re-plans on (docs/twin.md, "Thermal quantities"): called on the twin's thread
        # with {config key: estimate} of every thermal quantity beyond its interval, when one leaves it; what it
        # returns (what the controller does about it) is added to the event before the other listeners see it
        self.on_thermal_change: Callable[[dict[str, float]], str | None] | None = None
        self.thermal_hook_errors: list[str] = []
        self.twin.diagnose_fn = self._diagnose if self.twin.settings.diagnose else None
        self.twin.listeners.insert(0, self)  # first: the event reaches the sinks with what the controller did

    # a listener of its own twin: a mismatch may stop the rig (``[twin] stop_on_mismatch``)
    def prediction(self, msg: dict[str, float]) -> None:
        pass

    def mismatch(self, event: MismatchEvent, final: bool) -> None:
        """Called once, when the monitor fires (its diagnosis is announced to the others only)."""
        if self.twin.settings.stop_on_mismatch and self.on_stop is not None:
            self.on_stop(event.text())

    def thermal(self, event: ThermalEvent) -> None:
        """A thermal quantity left its interval: the controller's hook gets the updated config values,
        when the fit explains the window (a failing hook is recorded, never stops the twin)."""
        if self.on_thermal_change is None or not event.explained:  # a window the thermal quantities do not
            return                                                   # explain is another difference
        try:
            event.action = self.on_thermal_change(dict(event.updates)) or ""
        except Exception as e:
            self.thermal_hook_errors.append(f"{type(e).__name__}: {e}")

    def _diagnose(self, event: MismatchEvent, rec: Any, x0: Any, xd0: Any) -> None:
        th = threading.Thread(target=self._run_diagnosis, args=(event, rec, x0, xd0), name="twin-diagnosis",
                              daemon=True)
        self._threads.append(th)
        th.start()

    def _run_diagnosis(self, event: MismatchEvent, rec: Any, x0: Any, xd0: Any, note: str = "") -> None:
        from rehab_hil.twin.diagnosis import diagnose

        try:
            d = diagnose(get_plant(self.cfg.plant), self.cfg, rec, x0, xd0)
            event.cause = d.text + note
            event.candidates = [{"name": c.name, "family": c.family, "relative_change": c.relative_change,
                                 "reduction": c.reduction, "text": c.text} for c in d.causes[:3]]
        except Exception as e:  # a failed diagnosis leaves the event standing, said so
            event.cause = f"not diagnosed ({type(e).__name__}: {e})"
        self._announce(event)

    def _announce(self, event: MismatchEvent) -> None:
        for lst in self.twin.listeners:
            if lst is not self:
                lst.mismatch(event, final=True)

    def close(self) -> dict[str, Any]:
        """Finish the twin (and wait for running diagnoses); the ``twin`` and ``model_events`` metadata."""
        self.live.close()
        end = time.monotonic() + DIAGNOSIS_WAIT_S
        for th in self._threads:
            th.join(max(0.0, end - time.monotonic()))
        for ev, window in self.twin.take_pending(MIN_WINDOW_S):  # the session ended inside its window (a
            rec = window[0]                                       # trip): what there is, said so
            self._run_diagnosis(ev, *window, note=f" (on the {rec.t[-1] - rec.t[0]:.1f} s the session had left)")
        pending = [ev for ev in self.twin.monitor.events if not ev.cause]
        for ev in pending:  # found too close to the end for a window, or diagnosis off
            ev.cause = "" if not self.twin.settings.diagnose else "not diagnosed: the session ended first"
            if self.twin.settings.diagnose:
                self._announce(ev)
        summary = self.twin.summary()
        summary["dropped_records"] = self.live.dropped
        if self.thermal_hook_errors:
            summary["thermal_hook_errors"] = self.thermal_hook_errors
        if self.live.error is not None:
            summary["error"] = f"{type(self.live.error).__name__}: {self.live.error}"
        out = {"twin": summary, "model_events": [model_event(ev) for ev in self.twin.monitor.events]}
        patient = self.twin.patient(self.cycle_s)
        if patient:
            out["patient"] = patient
        return out


def model_event(ev: MismatchEvent) -> dict[str, Any]:
    """One ``metadata.json`` ``model_events`` entry."""
    return {"kind": ev.kind, "t_s": round(ev.t_s, 4), "detected_s": round(ev.detected_s, 4), "channel": ev.channel,
            "size": ev.size, "size_counts": ev.size_counts, "cause": ev.cause, "candidates": ev.candidates}


def start_twin(cfg: Any, binding: DeviceBinding, period_s: float, run_dir: str | Path | None = None,
               sinks: Sequence[Any] = (), zenoh: Any = None, cycle_s: float | None = None,
               lockstep: bool = False) -> TwinRun:
    """The twin for ``cfg`` (its ``[twin]`` table, or the defaults), writing ``twin.csv`` into ``run_dir``;
    its predictions and model events are offered to ``sinks`` (the recorder, the Foxglove feed) and
    published by ``zenoh`` (a ``TelemetryPublisher``) on ``rehab/<rig>/twin``. ``cycle_s``: the
    session's open-close period (per-cycle interaction estimates); ``lockstep``: the loop waits for a
    twin that falls behind instead of the twin dropping records, so a lockstep session's twin is as
    deterministic as the rest. Raises ``TwinSetupError`` (one line)."""
    settings = cfg.twin or TwinSection()
    listeners: list[Any] = [SinkOutput(s) for s in sinks]
    if zenoh is not None:
        listeners.append(ZenohOutput(zenoh))
    try:
        # a lockstep session waits for its twin (wait_when_full): its speed only sets how long the session takes
        twin = Twin(cfg, binding, period_s, settings, out_dir=run_dir, listeners=listeners, cycle_s=cycle_s,
                    check_speed=not lockstep)
    except ValueError as e:  # a TwinSetupError, or a model the twin cannot bind: one line either way
        raise TwinSetupError(str(e)) from None
    return TwinRun(LiveTwin(twin, wait_when_full=lockstep), cfg, cycle_s)
