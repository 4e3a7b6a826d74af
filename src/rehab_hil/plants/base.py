"""What every plant provides: canonical signal names, a diagram builder and scenarios."""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from rehab_hil.models.system import Diagram, Part, SimulationResult

__all__ = [
    "PLANTS",
    "AdcChannel",
    "DeviceBinding",
    "DutyInput",
    "PlantSpec",
    "Scenario",
    "get_plant",
    "register",
    "run_scenario",
]


@dataclass
class Scenario:
    """A closed- or open-loop experiment: extra parts (reference, controller), external input
    arrays per step, and a function that turns the result into metrics."""

    name: str
    n_steps: int
    parts: list[Part] = field(default_factory=list)
    inputs: Mapping[str, float | np.ndarray] = field(default_factory=dict)
    extra_outputs: tuple[str, ...] = ()
    metrics: Callable[[SimulationResult], dict[str, float]] | None = None


@dataclass(frozen=True)
class DutyInput:
    """A plant input driven by a PWM channel: value = scale * duty (0..1), negated when the
    channel's direction pin is set and ``signed`` (an H-bridge); e.g. motor_voltage_v = 24 * duty."""

    channel: int
    scale: float
    signed: bool = False


@dataclass(frozen=True)
class AdcChannel:
    """An analog input the firmware samples: counts = offset + per_unit * signal, clipped to 0..1023."""

    signal: str
    counts_per_unit: float
    offset_counts: float = 0.0


@dataclass
class DeviceBinding:
    """How a plant sits behind the rig's I/O: PWM duty in, encoder counts and ADC counts out.

    Used by the simulated devices (Python on a pty, and the firmware in simavr) to close the
    loop with a plant model, and by the host to calibrate counts back into SI units."""

    parts: list[Part]
    duty_inputs: dict[str, DutyInput]
    constant_inputs: dict[str, float]
    encoder_signal: str  # plant signal in rad
    encoder_counts_per_rev: int
    adc: tuple[AdcChannel, ...]
    step_s: float
    substeps: int


@dataclass
class PlantSpec:
    """A plant: CSV signal names (inputs, outputs), its parts, its scenarios."""

    name: str
    inputs: tuple[str, ...]
    outputs: tuple[str, ...]
    build: Callable[[Any], list[Part]]
    scenarios: dict[str, Callable[..., Scenario]]
    step: Callable[[Any], tuple[float, int]]  # config -> (step_s, substeps)
    device: Callable[[Any], DeviceBinding] | None = None  # config -> rig I/O binding


PLANTS: dict[str, PlantSpec] = {}


def register(spec: PlantSpec) -> PlantSpec:
    """Register a plant; its ``build`` and its rig ``device`` binding both append the config's
    ``effects`` (docs/discrepancy.md), so a fitted model drives the simulated rig too."""
    build, device = spec.build, spec.device

    def with_effects(cfg: Any, parts: list[Part]) -> list[Part]:
        effects = getattr(cfg, "effects", None)
        if not effects:
            return parts
        from rehab_hil.discrepancy.effects import attach

        return attach(spec.name, cfg, parts, [(e.name, e.params) for e in effects])

    def build_with_effects(cfg: Any) -> list[Part]:
        return with_effects(cfg, build(cfg))

    spec.build = build_with_effects
    if device is not None:
        def device_with_effects(cfg: Any) -> DeviceBinding:
            binding = device(cfg)
            binding.parts = with_effects(cfg, binding.parts)
            return binding

        spec.device = device_with_effects
    PLANTS[spec.name] = spec
    return spec


def get_plant(name: str) -> PlantSpec:
    if name not in PLANTS:
        raise KeyError(f"unknown plant {name!r}; known: {sorted(PLANTS)}")
    return PLANTS[name]


def run_scenario(spec: PlantSpec, cfg: Any, scenario: Scenario,
                 extra_parts: list[Part] | None = None) -> SimulationResult:
    """Compile plant + scenario (+ extra effect parts) and simulate; records CSV signals."""
    diagram = Diagram([*spec.build(cfg), *(extra_parts or []), *scenario.parts])
    step_s, substeps = spec.step(cfg)
    system = diagram.compile(step_s, substeps)
    record = [*spec.inputs, *spec.outputs, *scenario.extra_outputs]
    record = [s for s in dict.fromkeys(record) if s in diagram.producers]
    external = {k: v for k, v in scenario.inputs.items() if k in system.input_names}
    res = system.simulate(scenario.n_steps, external, outputs=record)
    for name in spec.inputs:  # external inputs are recorded as given
        if name not in res.signals and name in system.input_names:
            res.signals[name] = system.input_matrix(scenario.n_steps, external)[:, system.input_names.index(name)]
    return res
