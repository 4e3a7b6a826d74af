"""Changes that start mid-session: a plant's parameters, constant inputs and PWM scales moved
from their start values to their end values over time (``[[effects]]`` / ``[[changes]]`` with
``start_s`` and ``ramp_s``; docs/models.md, "Changes during a session").

The plant is built once per scheduled item at its end value and once with every item at its start
value; the builds must have the same structure, so each item is a set of parameter-vector entries
(and constant inputs, and PWM scales) moving by a fixed delta: value(t) = start + alpha(t) * delta,
alpha = 0 before ``start_s``, linear over ``ramp_s``, 1 after. Items may not move the same entry.
This module knows no plant: ``build_schedule`` takes a function that builds the rig binding with a
given set of items at their end value.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from rehab_hil.models.system import Diagram

__all__ = ["Schedule", "ScheduleError", "ScheduledItem", "Timing", "build_schedule"]


class ScheduleError(ValueError):
    """A scheduled item that cannot be applied; ``key`` is its config key (``changes.0.key``)."""

    def __init__(self, key: str, message: str) -> None:
        self.key, self.message = key, message
        super().__init__(f"{key}: {message}")


@dataclass(frozen=True)
class Timing:
    """When an item acts: from ``start_s`` [s] after the session's start, reaching its end value
    ``ramp_s`` [s] later (0: at once)."""

    start_s: float = 0.0
    ramp_s: float = 0.0

    def __post_init__(self) -> None:
        for name in ("start_s", "ramp_s"):
            v = getattr(self, name)
            if not (math.isfinite(v) and v >= 0.0):
                raise ValueError(f"{name} must be a finite number >= 0 [s], got {v!r}")

    @property
    def scheduled(self) -> bool:
        """True unless the item acts at once from the start (then it is simply part of the plant)."""
        return self.start_s > 0.0 or self.ramp_s > 0.0

    def alpha(self, t_s: float) -> float:
        """The share of the way from start to end value at session time ``t_s`` [s], 0..1."""
        if t_s < self.start_s:
            return 0.0
        if self.ramp_s <= 0.0:
            return 1.0
        return min(1.0, (t_s - self.start_s) / self.ramp_s)


@dataclass(frozen=True)
class ScheduledItem:
    """One scheduled config entry as what it moves: parameter-vector entries, constant inputs and
    PWM scales (each by a delta from its start value to its end value)."""

    key: str  # the config entry, e.g. "effects.1" or "changes.0"
    timing: Timing
    param_index: np.ndarray  # entries of the plant's parameter vector
    param_delta: np.ndarray
    input_delta: Mapping[str, float]  # constant plant input -> delta (its unit)
    scale_delta: Mapping[str, float]  # duty-driven plant input -> delta of its full-duty value


@dataclass(frozen=True)
class Schedule:
    """Every scheduled item of a plant, with the start values they move from."""

    params: np.ndarray  # the parameter vector at the start
    inputs: Mapping[str, float]  # constant inputs at the start
    scales: Mapping[str, float]  # full-duty values of the duty-driven inputs at the start
    items: tuple[ScheduledItem, ...]

    def at(self, t_s: float) -> tuple[np.ndarray, dict[str, float], dict[str, float]]:
        """(parameter vector, constant inputs, duty scales) at session time ``t_s`` [s]."""
        p = self.params.copy()
        inputs, scales = dict(self.inputs), dict(self.scales)
        for item in self.items:
            a = item.timing.alpha(t_s)
            p[item.param_index] += a * item.param_delta
            for name, d in item.input_delta.items():
                inputs[name] += a * d
            for name, d in item.scale_delta.items():
                scales[name] += a * d
        return p, inputs, scales


def _structure(binding: Any) -> tuple[Any, ...]:
    """What must not differ between the start and end builds: the diagram's layout and every binding
    field other than parameter values, constant-input values and duty scales."""
    inputs = (*binding.duty_inputs, *binding.constant_inputs)
    layout = Diagram(binding.parts, inputs=inputs, sums=binding.sums).layout
    skip = {"parts", "constant_inputs", "duty_inputs", "schedule"}
    rest = tuple((f.name, getattr(binding, f.name)) for f in dataclasses.fields(binding) if f.name not in skip)
    duty = tuple((k, dataclasses.replace(d, scale=0.0)) for k, d in binding.duty_inputs.items())
    return layout, rest, duty, tuple(binding.constant_inputs)


def _values(binding: Any) -> tuple[np.ndarray, dict[str, float], dict[str, float]]:
    p = np.concatenate([part.param_values for part in binding.parts]) if binding.parts else np.zeros(0)
    return p, dict(binding.constant_inputs), {k: d.scale for k, d in binding.duty_inputs.items()}


def build_schedule(keys: Sequence[str], timings: Sequence[Timing],
                   binding_with: Callable[[frozenset[int]], Any]) -> Schedule:
    """The schedule of items ``keys`` (config entries) acting at ``timings``; ``binding_with(ends)``
    builds the rig binding (``DeviceBinding``) with the items numbered in ``ends`` at their end value
    and the others at their start value. Raises ScheduleError naming the item (``<key>.key`` for a
    change, the entry for an effect) when an item changes the plant's structure, changes nothing, or
    moves what another item moves."""
    start = binding_with(frozenset())
    shape = _structure(start)
    p0, in0, sc0 = _values(start)
    items: list[ScheduledItem] = []
    owner: dict[str, str] = {}  # moved entry -> the item that moves it
    names = [f"{part.name}.{p}" for part in start.parts for p in part.params]
    for i, (key, timing) in enumerate(zip(keys, timings, strict=True)):
        end = binding_with(frozenset({i}))
        if _structure(end) != shape:
            raise ScheduleError(key, "changes the plant's structure (its parts, wiring, inputs or sensors), not "
                                "only values: it cannot change mid-session")
        p1, in1, sc1 = _values(end)
        idx = np.flatnonzero(p1 != p0)
        d_in = {k: in1[k] - in0[k] for k in in0 if in1[k] != in0[k]}
        d_sc = {k: sc1[k] - sc0[k] for k in sc0 if sc1[k] != sc0[k]}
        moved = [names[j] for j in idx] + [f"input {k}" for k in d_in] + [f"scale {k}" for k in d_sc]
        if not moved:
            raise ScheduleError(key, "changes nothing the simulated rig's plant uses (no model parameter, constant "
                                "input or PWM scale)")
        for m in moved:
            if m in owner:
                raise ScheduleError(key, f"moves {m}, which {owner[m].removesuffix('.key')} moves too: schedule "
                                    "them as one")
            owner[m] = key
        items.append(ScheduledItem(key, timing, idx, (p1 - p0)[idx], d_in, d_sc))
    return Schedule(p0, in0, sc0, tuple(items))
