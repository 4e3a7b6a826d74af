"""The plant contract: one ``Plant`` declaration per plant, registered once when its class is made.

A plant declares its config schema (on the shared ``PlantConfig``), its parts, its scenarios, its
CSV signals and its typed ports (``models/ports.py``). Everything else is derived here: the
integration step, the ``[[effects]]`` a config adds (``compose``, the same for simulation and for
the simulated rig), the rig binding (PWM duty in, encoder and ADC counts out) and a scenario's run.
``plants()`` finds plant modules by scanning this package, so a fourth plant is one module, its
parts and one config.
"""

from __future__ import annotations

import difflib
import importlib
import pkgutil
from collections.abc import Callable, Iterable, Mapping, Sequence
from types import MappingProxyType
from typing import Any, ClassVar

import numpy as np

from rehab_hil.effects import applicable, attach
from rehab_hil.interfaces import AdcChannel, CommandInterface, DeviceBinding
from rehab_hil.models.ports import MeasuredPort, Ports
from rehab_hil.models.system import Diagram, Part, SimulationResult
from rehab_hil.plants.changes import scheduled, scheduled_binding
from rehab_hil.plants.experiments import Excitation, FitParameter, Scenario
from rehab_hil.plants.sections import PlantConfig

__all__ = ["Plant", "compose", "get_plant", "plant_names", "plants", "run_scenario"]

_REGISTRY: dict[str, type[Plant]] = {}


class Plant:
    """One plant: its schema, parts, ports, signals and scenarios. Subclasses that set ``name``
    register themselves; ``compose``, ``diagram``, ``step`` and ``device`` come from here."""

    name: ClassVar[str]
    config: ClassVar[type[PlantConfig]]
    inputs: ClassVar[tuple[str, ...]]  # CSV input signals (SI units in the names)
    outputs: ClassVar[tuple[str, ...]]  # CSV output signals
    optional_inputs: ClassVar[tuple[str, ...]] = ()  # a recording may lack these (taken as zero)
    scenarios: ClassVar[Mapping[str, Callable[..., Scenario]]] = {}
    excitation: ClassVar[Excitation | None] = None
    fit_parameters: ClassVar[tuple[FitParameter, ...]] = ()  # nominal parameters the discrepancy workflow fits
    # how reports speak of this plant: what it is, its axis, its power stage, and whether the effects'
    # sources are the seed papers of the finger rigs ("seed") or general references ("general")
    vocabulary: ClassVar[Mapping[str, str]] = MappingProxyType({"thing": "finger rig", "axis": "joint axis",
                                                                "actuator": "PWM power stage", "sources": "seed"})

    def __init_subclass__(cls, register: bool = True, **kwargs: Any) -> None:
        super().__init_subclass__(**kwargs)
        if register and "name" in cls.__dict__:
            _REGISTRY[cls.name] = cls

    @staticmethod
    def build(cfg: PlantConfig) -> list[Part]:
        """The nominal plant as parts (a fresh list each call)."""
        raise NotImplementedError

    @staticmethod
    def ports(cfg: PlantConfig) -> Ports:
        """The plant's typed ports under ``cfg``."""
        raise NotImplementedError

    @classmethod
    def step(cls, cfg: PlantConfig) -> tuple[float, int]:
        """(sample step [s], RK4 substeps) from ``[simulation]``."""
        return cfg.simulation.step_s, cfg.simulation.substeps

    @classmethod
    def n_steps(cls, cfg: PlantConfig, duration_s: float) -> int:
        return max(1, round(duration_s / cls.step(cfg)[0]))

    @classmethod
    def input_signals(cls, cfg: PlantConfig) -> tuple[str, ...]:
        """The input columns a record of this plant under ``cfg`` carries (default: ``inputs``; a motor
        axis commanded in torque or current takes that command instead of a voltage)."""
        return cls.inputs

    @classmethod
    def external_inputs(cls, cfg: PlantConfig) -> tuple[str, ...]:
        """Signals the plant's diagram may take from outside: its inputs and config constants."""
        return tuple(dict.fromkeys([*cls.input_signals(cfg), *cls.ports(cfg).constants]))

    @classmethod
    def actuator_power_w(cls, cfg: PlantConfig, effort: np.ndarray, velocity_rad_s: np.ndarray) -> np.ndarray:
        """Electrical power into the actuator [W] for an effort on its input (and the joint velocity,
        for a motor's back-EMF): what a session's energy per cycle sums. Default: not modelled (nan)."""
        return np.full(np.shape(effort), np.nan)

    @classmethod
    def diagram(cls, cfg: PlantConfig, extra_parts: Sequence[Part] = (), extra_inputs: Iterable[str] = (),
                extra_sums: Iterable[str] = ()) -> Diagram:
        """The plant's diagram (``compose``: nominal parts plus the config's effects) with extra parts
        (a reference, a controller), the plant's external inputs plus ``extra_inputs``, and the
        plant's summable signals (``Ports.sums``) plus ``extra_sums``."""
        return Diagram([*compose(cls, cfg), *extra_parts], inputs=(*cls.external_inputs(cfg), *extra_inputs),
                       sums=(*cls.ports(cfg).sums, *extra_sums))

    @classmethod
    def applicable_effects(cls, cfg: PlantConfig) -> list[str]:
        return [e.name for e in applicable(cls.ports(cfg))]

    @classmethod
    def device(cls, cfg: PlantConfig) -> DeviceBinding:
        """The rig's view, from the ports: actuators on PWM channels, the encoder port, ADC ports.

        A config that schedules changes (``start_s``/``ramp_s`` on an effect, ``[[changes]]``) gets the
        plant as it is at the session's start plus the schedule that a simulated rig applies."""
        if not scheduled(cfg):
            return cls._binding(cfg)
        return scheduled_binding(cls._binding, cfg)

    @classmethod
    def _binding(cls, cfg: PlantConfig) -> DeviceBinding:
        """The rig binding of ``cfg`` as written (every effect acting from the start)."""
        ports = cls.ports(cfg)
        parts = compose(cls, cfg)
        feeds = {(p.name, port): terms for p in parts for port, terms in p.connections.items()}

        def source(m: MeasuredPort) -> str:
            assert m.wire is not None
            if not m.wire.consumers:
                return m.wire.signal
            return feeds[m.wire.consumers[0]][0][0]

        enc = next((m for m in ports.measured if m.sensor == "encoder" and m.wire is not None), None)
        adc = tuple(AdcChannel(m.wire.signal, m.counts_per_unit, m.offset_counts, m.kind, m.unit, source(m))
                    for m in ports.measured if m.sensor == "adc" and m.wire is not None)
        step_s, substeps = cls.step(cfg)
        return DeviceBinding(
            parts=parts,
            duty_inputs={a.signal: CommandInterface(a.signal, a.unit, a.duty_channel, a.duty_scale, a.signed)
                         for a in ports.actuators},
            constant_inputs=dict(ports.constants),
            encoder_signal=enc.wire.signal if enc and enc.wire else None,
            encoder_counts_per_rev=int(enc.counts_per_unit) if enc else 0,
            adc=adc, step_s=step_s, substeps=substeps,
            encoder_source=source(enc) if enc else "", plant=cls.name, angle_output=enc.signal if enc else "",
            encoder_direction=int(getattr(getattr(cfg, "encoder", None), "direction", 1)),
            sums=ports.sums,
        )


def compose(plant: type[Plant], cfg: PlantConfig) -> list[Part]:
    """The plant's parts plus the config's ``[[effects]]``: the one place effects are added, for
    simulation, replay and the simulated rig alike. Every effect acts from the start and
    ``[[changes]]`` are not applied: their schedule is the simulated rig's (``Plant.device``)."""
    parts = plant.build(cfg)
    effects = [(e.name, e.params) for e in getattr(cfg, "effects", ())]
    if not effects:
        return parts
    return attach(plant.name, plant.ports(cfg), plant.step(cfg)[0], parts, effects)


_NOT_PLANTS = {"changes", "experiments", "registry", "sections", "thermal"}  # this package's helpers


def plants() -> dict[str, type[Plant]]:
    """Every registered plant; the first call imports each module of ``rehab_hil.plants``."""
    if not getattr(plants, "_scanned", False):
        pkg = importlib.import_module("rehab_hil.plants")
        for mod in pkgutil.iter_modules(pkg.__path__):
            if not mod.name.startswith("_") and mod.name not in _NOT_PLANTS:
                importlib.import_module(f"rehab_hil.plants.{mod.name}")
        plants._scanned = True  # type: ignore[attr-defined]
    return _REGISTRY


def plant_names() -> list[str]:
    return sorted(plants())


def get_plant(name: str) -> type[Plant]:
    known = plants()
    if name not in known:
        near = difflib.get_close_matches(name, known, n=1)
        hint = f" (did you mean {near[0]!r}?)" if near else ""
        raise KeyError(f"unknown plant {name!r}{hint}; known: {sorted(known)}")
    return known[name]


def run_scenario(spec: type[Plant], cfg: PlantConfig, scenario: Scenario,
                 extra_parts: list[Part] | None = None) -> SimulationResult:
    """Compile plant + scenario (+ extra effect parts) and simulate; records CSV signals."""
    diagram = spec.diagram(cfg, [*(extra_parts or []), *scenario.parts], extra_inputs=scenario.inputs,
                           extra_sums=scenario.sums)
    step_s, substeps = spec.step(cfg)
    system = diagram.compile(step_s, substeps)
    record = [*spec.input_signals(cfg), *spec.outputs, *scenario.extra_outputs]
    record = [s for s in dict.fromkeys(record) if s in diagram.producers]
    external = {k: v for k, v in scenario.inputs.items() if k in system.input_names}
    res = system.simulate(scenario.n_steps, external, outputs=record)
    for name in spec.input_signals(cfg):  # external inputs are recorded as given
        if name not in res.signals and name in system.input_names:
            res.signals[name] = system.input_matrix(scenario.n_steps, external)[:, system.input_names.index(name)]
    return res
