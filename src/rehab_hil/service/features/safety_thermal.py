"""The twin's thermal estimates into the safety's temperature estimate, only where they are stricter.

The safety supervisor's estimate is the plant's thermal model of its actuator on the config's values
(``plants/thermal.py``). When the live twin finds a thermal quantity beyond its interval around the config
(``twin/thermal.py``'s ``thermal_change``, a window the thermal quantities explain), each quantity is taken
at the strict end of its 95 % interval (the room's value + its half-width, the convection's - its
half-width, the supply's +) and only if that makes the model hotter than the values in force: a warmer
room, less convection, a higher supply; never a cooler room, a draft or a sagging supply, which would
loosen the limit. Which way is hotter is the model's own answer (``hotter_direction``: the steady
temperature at full and half duty with the value raised 2 %), not a table.

A tightening carries the model's parameters on the new values and the state the model would have reached
on them over the session's drive so far (``ActuatorThermal.final_state``: re-run from the start on the
duties the loop sent, which this feature's feed keeps), so the estimate is right from then on, not only
in a wire's time constant. It reaches the loop between two cycles: through the mailbox to a loop process
(``LoopProcess.tighten_thermal``), or on the loop's own thread from this feature's feed (``LocalLoop``;
a lockstep session catches its twin up after each of its windows, so the same session tightens at the
same point every run). Each is a ``safety_thermal`` event on ``/rig/event``, a line of the summary and an
entry of ``metadata.json`` ``safety_thermal``.
"""

from __future__ import annotations

import collections
import math
from collections.abc import Callable
from typing import Any

import numpy as np

from rehab_hil.loop.records import CommandRecord, EventRecord
from rehab_hil.loop.result import FeatureResult, RunResult
from rehab_hil.loop.thermal import ThermalTightening
from rehab_hil.plants.changes import with_values
from rehab_hil.plants.thermal import ActuatorThermal, steady_temperature_c
from rehab_hil.service.features.base import Feature, LoopHandle, SessionParts

__all__ = ["EVENT", "SafetyThermalFeature", "Tightener", "hotter_direction"]

EVENT = "safety_thermal"  # the event's kind on /rig/event
CATCH_UP_WAIT_S = 120.0  # a lockstep session waits this long at most for its twin's window (a fit: ~1 s idle)


def hotter_direction(cfg: Any, key: str, max_duty: float = 1.0) -> int:
    """+1 if raising ``key`` makes the actuator's model hotter at full and at half duty, -1 if lowering
    it does, 0 if neither alone (then the key never tightens the safety)."""
    def steady(c: Any) -> tuple[float, float]:
        m = ActuatorThermal.of(c)
        assert m is not None
        return steady_temperature_c(m, max_duty), steady_temperature_c(m, 0.5 * max_duty)

    value = float(_value(cfg, key))
    base, up = steady(cfg), steady(with_values(cfg, {key: value * 1.02 if value else 0.02}))
    if all(u > b for u, b in zip(up, base, strict=True)):
        return 1
    if all(u < b for u, b in zip(up, base, strict=True)):
        return -1
    return 0


def _value(cfg: Any, key: str) -> Any:
    obj = cfg
    for part in key.split("."):
        obj = getattr(obj, part)
    return obj


class Tightener:
    """Judges the twin's estimates against the values in force and builds the tightenings; see the module."""

    def __init__(self, cfg: Any, keys: list[str], step_s: float) -> None:
        self.cfg, self.step_s = cfg, step_s
        self.config = {k: float(_value(cfg, k)) for k in keys}
        self.values = dict(self.config)  # in force in the safety's estimate
        self.direction = {k: hotter_direction(cfg, k, cfg.rig.limits.max_duty) for k in keys}
        self.times: list[float] = []  # the duty the loop sent, from each command's time on
        self.duties: list[float] = []

    def record(self, t_s: float, duty: float) -> None:
        self.times.append(t_s)
        self.duties.append(duty)

    def stricter(self, estimates: dict[str, dict[str, Any]], keys: list[str]) -> dict[str, float]:
        """Of ``keys``, those whose estimate, at the strict end of its interval, is stricter than in force."""
        out = {}
        for k in keys:
            sign, e = self.direction.get(k, 0), estimates.get(k)
            if sign == 0 or e is None:
                continue
            strict = e["value"] + sign * e["ci95"]
            if (strict - self.values[k]) * sign > 0.0:
                out[k] = strict
        return out

    def tightening(self, found_s: float, new: dict[str, float]) -> ThermalTightening:
        """The change to the values ``new``: the model on all values in force, and the state it gains."""
        before = ActuatorThermal.of(with_values(self.cfg, self.values))
        after_values = {**self.values, **new}
        after = ActuatorThermal.of(with_values(self.cfg, after_values))
        assert before is not None and after is not None
        duty = self._history()
        change = ThermalTightening(found_s, new, {k: self.values[k] for k in new}, after.params, after.constants,
                                   after.duty_scale, after.final_state(duty) - before.final_state(duty))
        self.values = after_values
        return change

    def _history(self) -> np.ndarray:
        """The duty per plant step from the session's start to the last command."""
        n = len(self.times)
        if n == 0:
            return np.zeros(0)
        t, d = np.asarray(self.times[:n]), np.asarray(self.duties[:n])
        grid = np.arange(0.0, t[-1] + 0.5 * self.step_s, self.step_s)
        at = np.searchsorted(t, grid + 1e-9, side="right") - 1
        return np.where(at >= 0, d[np.maximum(at, 0)], 0.0)


class SafetyThermalFeature(Feature):
    """With the twin, on a plant that models its actuator's heat: the safety takes its stricter estimates."""

    name = "safety_thermal"
    needs = ("twin",)

    def __init__(self) -> None:
        self.tightener: Tightener | None = None
        self.run: Any = None  # the TwinRun
        self.loop: LoopHandle | None = None
        self.pending: collections.deque[ThermalTightening] = collections.deque()
        self.outputs: list[Any] = []
        self.events: list[dict[str, Any]] = []
        self._next_catch_up = math.inf
        self._window_s = math.inf
        self._lockstep = False

    def open(self, parts: SessionParts) -> None:
        self.run = parts.features["twin"].run  # type: ignore[attr-defined]
        est = self.run.twin.thermal
        model = ActuatorThermal.of(parts.cfg)
        if est is None or model is None:
            return
        self.tightener = Tightener(parts.cfg, [q.key for q in est.quantities], model.step_s)
        found = parts.features
        self.outputs = [s for name in ("recording", "foxglove") if name in found for s in found[name].sinks()]
        self._window_s = est.window_samples * est.model.period_s
        margin = self.run.twin.settings.segment_s + parts.period_s  # the twin fits at a segment's end
        self._next_catch_up = self._window_s + margin
        self._lockstep = parts.lockstep

    def feeds(self) -> list[Callable[[CommandRecord], None]]:
        return [self._record] if self.tightener is not None else []

    def started(self, loop: LoopHandle) -> None:
        if self.tightener is None:
            return
        self.loop = loop
        self.run.on_thermal_change = _joined(self.run.on_thermal_change, self.request)

    def request(self, updates: dict[str, float]) -> str:
        """The twin's hook (its thread): the stricter of ``updates`` into the safety; says what it took."""
        tight = self.tightener
        assert tight is not None
        est = self.run.twin.thermal
        new = tight.stricter({e["key"]: e for e in est.estimates()}, list(updates))
        if not new:
            return ""
        found_s = float(est.history[-1]["t_end_s"]) if est.history else math.nan
        change = tight.tightening(found_s, new)
        text = f"the safety's temperature estimate takes {change.text()}"
        self.events.append({"found_s": found_s, "values": dict(change.values), "previous": dict(change.previous)})
        for sink in self.outputs:
            sink.offer(EventRecord(found_s, EVENT, text))
        self.pending.append(change)
        if self.loop is not None and self.loop.separate:
            self._deliver()
        return text

    def _record(self, rec: CommandRecord) -> None:
        """Each command (the loop's thread in a local loop): its duty kept; a lockstep session's twin caught
        up after each window; tightenings waiting handed to the loop."""
        cmd = rec.command
        assert self.tightener is not None
        self.tightener.record(rec.time_s, max(cmd.duty) if cmd.enable else 0.0)
        if self._lockstep and rec.time_s >= self._next_catch_up:
            self._next_catch_up += self._window_s
            self.run.live.catch_up(CATCH_UP_WAIT_S)
        if self.pending:
            self._deliver()

    def _deliver(self) -> None:
        """Hand the waiting tightenings to the loop, oldest first (one the mailbox has no room for waits)."""
        while self.pending and self.loop is not None:
            if not self.loop.tighten_thermal(self.pending[0]):
                return
            self.pending.popleft()

    def finish(self, result: RunResult) -> FeatureResult | None:
        tight = self.tightener
        if tight is None:
            return None
        taken = list(result.thermal_changes)
        for ev, got in zip(self.events, taken, strict=False):
            ev.update(applied_s=got["t_s"], temperature_before_c=got["temperature_before_c"],
                      temperature_after_c=got["temperature_after_c"])
        summary = {"config": tight.config, "values": tight.values, "changes": self.events}
        lines = tuple(("safety temperature", _line(ev)) for ev in self.events) or (
            ("safety temperature", "the plant's model on the config's values (the twin found none stricter)"),)
        return FeatureResult(self.name, summary, {"safety_thermal": summary}, lines=lines)


def _line(ev: dict[str, Any]) -> str:
    """A tightening in the run summary: the values, when found and when taken, the estimate's step."""
    vals = ", ".join(f"{k} {ev['previous'][k]:.4g} -> {v:.4g}" for k, v in ev["values"].items())
    taken = (f", taken at {ev['applied_s']:.2f} s: estimate {ev['temperature_before_c']:.1f} -> "
             f"{ev['temperature_after_c']:.1f} C") if "applied_s" in ev else ", not taken (the loop had ended)"
    return f"{vals} (the twin's at {ev['found_s']:.1f} s){taken}"


def _joined(other: Callable[[dict[str, float]], Any] | None,
            safety: Callable[[dict[str, float]], str]) -> Callable[[dict[str, float]], str]:
    """A thermal-change hook that tells the safety first, then ``other`` (the re-plan, a user's own), even
    when the safety's call raises; what each says, joined."""
    if other is None:
        return safety

    def hook(updates: dict[str, float]) -> str:
        said = ""
        try:
            said = safety(updates)
        finally:
            more = other(updates) or ""
        return "; ".join(s for s in (said, more) if s)
    return hook
