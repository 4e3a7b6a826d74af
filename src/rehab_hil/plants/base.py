"""The plant contract: one ``Plant`` declaration per plant, registered once when its class is made.

A plant declares its config schema (on the shared ``PlantConfig``: plant, simulation, rig,
effects), its parts, its scenarios, its CSV signals and its typed ports (``models/ports.py``).
Everything else is derived here: the integration step, the ``[[effects]]`` a config adds
(``compose``, the same for simulation and for the simulated rig), and the rig binding (PWM duty
in, encoder and ADC counts out). ``rehab_hil.plants`` finds plant modules by scanning its own
package, so a fourth plant is one module, its parts and one config.
"""

from __future__ import annotations

import difflib
import importlib
import pkgutil
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any, ClassVar, Literal

import numpy as np
from pydantic import BaseModel, ValidationError

from rehab_hil.config import Field, RigSection, Section, SimulationSection, TwinSection, model_validator
from rehab_hil.control.cascade import RecordedControllerSection
from rehab_hil.effects import EFFECTS, applicable, attach, check_spec
from rehab_hil.importing import ImportMapping
from rehab_hil.interfaces import CommandInterface, StateInterface
from rehab_hil.models.ports import MeasuredPort, Ports
from rehab_hil.models.schedule import Schedule, ScheduleError, Timing, build_schedule
from rehab_hil.models.system import Diagram, Part, SimulationResult

__all__ = [
    "AdcChannel",
    "ChangeSpec",
    "DeviceBinding",
    "DutyInput",
    "EffectSpec",
    "EncoderSection",
    "Excitation",
    "FitParameter",
    "ForceSensorSection",
    "Plant",
    "PlantConfig",
    "Scenario",
    "compose",
    "get_plant",
    "multisine",
    "plant_names",
    "plants",
    "random_levels",
    "run_scenario",
    "scheduled",
    "with_change",
]


@dataclass
class Scenario:
    """A closed- or open-loop experiment: extra parts (reference, controller), external input
    arrays per step, the signals its parts sum onto beyond the plant's (a feedforward plus a
    feedback effort), and a function that turns the result into metrics."""

    name: str
    n_steps: int
    parts: list[Part] = field(default_factory=list)
    inputs: Mapping[str, float | np.ndarray] = field(default_factory=dict)
    extra_outputs: tuple[str, ...] = ()
    metrics: Callable[[SimulationResult], dict[str, float]] | None = None
    sums: tuple[str, ...] = ()


@dataclass(frozen=True)
class Excitation:
    """How to excite a plant for identification (synthetic records, the discrepancy benchmark):
    input arrays for time stamps, one nominal parameter to mistune, and sensor noise per channel."""

    inputs: Callable[[np.ndarray, np.random.Generator], dict[str, np.ndarray]]
    mismatch: tuple[str, float]  # qualified parameter, factor
    noise: Mapping[str, float]  # channel -> standard deviation (its unit)


@dataclass(frozen=True)
class FitParameter:
    """A nominal parameter the discrepancy workflow may find off (docs/discrepancy.md): its config
    key, the diagram parameters (``"part.param"``) and external inputs scaled with it, and the
    corrected config value for a factor (default: the config value times the factor)."""

    config_key: str  # dotted key in the plant's TOML, e.g. "motor.kt_nm_per_a"
    diagram: tuple[str, ...] = ()
    inputs: tuple[str, ...] = ()
    to_config: Callable[[Any, float], float] | None = None
    # a physically coupled group (a weaker magnet lowers k_t and k_v together): the other config keys
    # corrected by the same factor, and the candidate's name ("motor flux (k_t, k_v)"); default: the key
    also: tuple[str, ...] = ()
    label: str = ""

    @property
    def name(self) -> str:
        return self.label or self.config_key


def multisine(t: np.ndarray, rng: np.random.Generator, amplitude: float, freqs_hz: tuple[float, ...],
               rest_share: float) -> np.ndarray:
    """Sum of sines with random phases, switched off during random rests (stick, cool down)."""
    u = sum(np.sin(2 * np.pi * f * t + rng.uniform(0, 2 * np.pi)) for f in freqs_hz)
    u = amplitude * np.asarray(u) / len(freqs_hz) * 1.6
    gate = np.sin(2 * np.pi * 0.11 * t + rng.uniform(0, 2 * np.pi)) > (2 * rest_share - 1)
    return u * gate if rest_share > 0 else u


def random_levels(t: np.ndarray, rng: np.random.Generator, levels: tuple[float, ...], hold_s: tuple[float, float],
            off_share: float) -> np.ndarray:
    """Piecewise-constant random levels (heating pulses and cooling rests of random length)."""
    out = np.zeros_like(t)
    start = 0.0
    while start < t[-1]:
        hold = rng.uniform(*hold_s)
        level = 0.0 if rng.random() < off_share else float(rng.choice(levels))
        out[(t >= start) & (t < start + hold)] = level
        start += hold
    return out


# --- configuration --------------------------------------------------------------------------


class EffectSpec(Section):
    """One added model effect (``[[effects]]`` tables): a library name and its parameters.

    Written by ``rehab-hil discrepancy`` into ``augmented.toml``; names and bounds are those of
    ``rehab_hil.effects`` (docs/discrepancy.md)."""

    name: str = Field(min_length=1, description="effect name in the library, e.g. coulomb_friction")
    params: dict[str, float] = Field(default_factory=dict, description="parameter values, SI units in the keys")
    start_s: float = Field(0.0, ge=0.0, description="on a simulated rig: seconds from the session's start before "
                           "the effect acts (docs/models.md, changes during a session) [s]")
    ramp_s: float = Field(0.0, ge=0.0, description="on a simulated rig: seconds from start_s over which its "
                          "magnitudes grow linearly from off to params (0: at once) [s]")

    @model_validator(mode="after")
    def _known(self) -> EffectSpec:
        check_spec(self.name, self.params)
        return self

    @property
    def timing(self) -> Timing:
        return Timing(self.start_s, self.ramp_s)


class ChangeSpec(Section):
    """A plant parameter that changes mid-session on a simulated rig (``[[changes]]`` tables): a
    dotted key of the plant's config, its new value (a factor, or a value in the key's unit), and
    when. A patient's stiffness doubling at 30 s, the supply sagging 8 % (docs/models.md)."""

    key: str = Field(min_length=1, description="dotted config key of this plant, e.g. contact.stiffness_n_per_m")
    scale: float | None = Field(None, description="the new value is the config value times this factor")
    value: float | None = Field(None, description="the new value, in the key's unit")
    start_s: float = Field(0.0, ge=0.0, description="seconds from the session's start before the change [s]")
    ramp_s: float = Field(0.0, ge=0.0, description="seconds from start_s over which the value moves linearly "
                          "from the config value to the new one (0: at once) [s]")

    @model_validator(mode="after")
    def _one_target(self) -> ChangeSpec:
        if (self.scale is None) == (self.value is None):
            raise ValueError("give exactly one of scale (a factor) or value (the new value, in the key's unit)")
        return self

    @property
    def timing(self) -> Timing:
        return Timing(self.start_s, self.ramp_s)


class PlantConfig(Section):
    """What every plant file has: its plant name, the integration step, the rig and added effects."""

    plant: str
    simulation: SimulationSection
    rig: RigSection
    effects: list[EffectSpec] = Field(default_factory=list, description="added model effects")
    changes: list[ChangeSpec] = Field(default_factory=list, description="plant parameters that change mid-session "
                                      "on a simulated rig (docs/models.md)")
    controllers: dict[str, Any] = Field(default_factory=dict, description="controller settings, one "
                                        "[controllers.<name>] table per controller (rehab_hil.controllers)")
    recorded_controller: RecordedControllerSection | None = Field(None, description="the controller that produced "
                                                                  "this plant's closed-loop records: the discrepancy "
                                                                  "workflow replays the loop from the reference")
    import_: ImportMapping | None = Field(None, alias="import", description="how a lab's logger files map onto "
                                          "the model's signals (rehab_hil.importing; rehab-hil import)")
    twin: TwinSection | None = Field(None, description="the live twin: the model beside the rig, its residual "
                                     "test and the online interaction estimate (docs/twin.md)")


class EncoderSection(Section):
    """The rig's quadrature encoder (x4 edges) and its homing (``rehab-hil run --home``)."""

    counts_per_rev: int = Field(ge=4, le=65_535, description="encoder edges per revolution of its axis (CONFIGURE "
                                "and HELLO carry it in 16 bits)")
    direction: Literal[1, -1] = Field(1, description="+1: counts rise with the angle; -1: an encoder wired (or "
                                      "mounted) the other way round, so counts fall as the angle rises")
    home_angle_deg: float = Field(0.0, ge=-360.0, le=360.0, description="joint angle at the pose `--home current` "
                                  "zeroes at [deg]")
    hard_stop_deg: float | None = Field(None, ge=-360.0, le=360.0, description="joint angle at the closed mechanical "
                                        "stop `--home hard-stop` drives to [deg]; unset: no hard-stop homing")
    homing_duty: float = Field(0.05, gt=0.0, le=0.3, description="duty of the hard-stop homing drive (slow, low "
                               "torque) [0..1]")


class ForceSensorSection(Section):
    """A Flexiforce (or load cell) on an ADC input: counts = offset_counts + counts_per_n * force."""

    counts_per_n: float = Field(gt=0.0, le=10000.0, description="ADC counts per newton")
    offset_counts: float = Field(ge=0.0, le=1023.0, description="ADC counts at zero force")


# --- rig binding ----------------------------------------------------------------------------


@dataclass(frozen=True)
class DutyInput:
    """A plant input driven by a PWM channel: value = scale * duty (0..1), negated when the
    channel's direction pin is set and ``signed`` (an H-bridge); e.g. motor_voltage_v = 24 * duty."""

    channel: int
    scale: float
    signed: bool = False
    unit: str = ""  # of the plant input (the actuator port's unit)


@dataclass(frozen=True)
class AdcChannel:
    """An analog input the firmware samples: counts = offset + per_unit * signal, clipped to 0..1023.

    ``signal`` names the channel (the model signal, also the recorded column); ``source`` is the
    plant signal the simulated device reads (differs when a sensor effect sits on the wire)."""

    signal: str
    counts_per_unit: float
    offset_counts: float = 0.0
    kind: str = "force"
    unit: str = "n"
    source: str = ""

    def __post_init__(self) -> None:
        if not self.source:
            object.__setattr__(self, "source", self.signal)


@dataclass
class DeviceBinding:
    """How a plant sits behind the rig's I/O: PWM duty in, encoder counts and ADC counts out.

    Used by the simulated devices (Python on a pty, and the firmware in simavr) to close the
    loop with a plant model, and by the host to calibrate counts back into SI units. Derived
    from the plant's ports (``Plant.device``)."""

    parts: list[Part]
    duty_inputs: dict[str, DutyInput]
    constant_inputs: dict[str, float]
    encoder_signal: str | None  # plant signal in rad (the recorded column); None: no encoder
    encoder_counts_per_rev: int
    adc: tuple[AdcChannel, ...]
    step_s: float
    substeps: int
    encoder_source: str = ""  # what the simulated encoder reads (differs under a sensor effect)
    plant: str = ""
    angle_output: str = ""  # the model's output for the encoder angle in degrees (the recorded column)
    encoder_direction: int = 1  # +1: counts rise with the angle; -1: the encoder counts the other way
    sums: tuple[str, ...] = ()  # the plant's summable signals (``Ports.sums``), for its diagram
    # what changes mid-session (``[[effects]]`` with start_s/ramp_s, ``[[changes]]``); ``parts`` are then
    # the plant at the session's start and ``PlantIO`` moves the values (models/schedule.py)
    schedule: Schedule | None = None

    def __post_init__(self) -> None:
        if not self.encoder_source and self.encoder_signal:
            self.encoder_source = self.encoder_signal

    @property
    def state_interfaces(self) -> tuple[StateInterface, ...]:
        """What the device measures: the encoder first (if any), then the ADC channels."""
        enc = (StateInterface(self.encoder_signal, "angle", "rad", "encoder"),) if self.encoder_signal else ()
        return (*enc, *(StateInterface(ch.signal, ch.kind, ch.unit, f"adc{i}")  # type: ignore[arg-type]
                        for i, ch in enumerate(self.adc)))

    @property
    def command_interfaces(self) -> tuple[CommandInterface, ...]:
        """What the host commands: each duty-driven plant input."""
        return tuple(CommandInterface(name, d.unit, d.channel, d.scale, d.signed)
                     for name, d in self.duty_inputs.items())

    def state(self, kind: str) -> StateInterface | None:
        """The first state interface of a kind (``angle``, ``force``, ``torque``, ``temperature``)."""
        return next((s for s in self.state_interfaces if s.kind == kind), None)

    @property
    def reference_column(self) -> str:
        """The recorded reference of the encoder angle, beside ``angle_output`` [deg]."""
        return self.angle_output.removesuffix("_deg") + "_reference_deg"


# --- the plant declaration and its registry -------------------------------------------------

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

    def __init_subclass__(cls, register: bool = True, **kwargs: Any) -> None:
        super().__init_subclass__(**kwargs)
        if register and "name" in cls.__dict__:
            _REGISTRY[cls.name] = cls

    @staticmethod
    def build(cfg: Any) -> list[Part]:
        """The nominal plant as parts (a fresh list each call)."""
        raise NotImplementedError

    @staticmethod
    def ports(cfg: Any) -> Ports:
        """The plant's typed ports under ``cfg``."""
        raise NotImplementedError

    @classmethod
    def step(cls, cfg: Any) -> tuple[float, int]:
        """(sample step [s], RK4 substeps) from ``[simulation]``."""
        return cfg.simulation.step_s, cfg.simulation.substeps

    @classmethod
    def n_steps(cls, cfg: Any, duration_s: float) -> int:
        return max(1, round(duration_s / cls.step(cfg)[0]))

    @classmethod
    def external_inputs(cls, cfg: Any) -> tuple[str, ...]:
        """Signals the plant's diagram may take from outside: its inputs and config constants."""
        return tuple(dict.fromkeys([*cls.inputs, *cls.ports(cfg).constants]))

    @classmethod
    def actuator_power_w(cls, cfg: Any, effort: np.ndarray, velocity_rad_s: np.ndarray) -> np.ndarray:
        """Electrical power into the actuator [W] for an effort on its input (and the joint velocity,
        for a motor's back-EMF): what a session's energy per cycle sums. Default: not modelled (nan)."""
        return np.full(np.shape(effort), np.nan)

    @classmethod
    def diagram(cls, cfg: Any, extra_parts: Sequence[Part] = (), extra_inputs: Iterable[str] = (),
                extra_sums: Iterable[str] = ()) -> Diagram:
        """The plant's diagram (``compose``: nominal parts plus the config's effects) with extra parts
        (a reference, a controller), the plant's external inputs plus ``extra_inputs``, and the
        plant's summable signals (``Ports.sums``) plus ``extra_sums``."""
        return Diagram([*compose(cls, cfg), *extra_parts], inputs=(*cls.external_inputs(cfg), *extra_inputs),
                       sums=(*cls.ports(cfg).sums, *extra_sums))

    @classmethod
    def applicable_effects(cls, cfg: Any) -> list[str]:
        return [e.name for e in applicable(cls.ports(cfg))]

    @classmethod
    def device(cls, cfg: Any) -> DeviceBinding:
        """The rig's view, from the ports: actuators on PWM channels, the encoder port, ADC ports.

        A config that schedules changes (``start_s``/``ramp_s`` on an effect, ``[[changes]]``) gets the
        plant as it is at the session's start plus the schedule that a simulated rig applies."""
        if not scheduled(cfg):
            return cls._binding(cfg)
        return _scheduled_binding(cls, cfg)

    @classmethod
    def _binding(cls, cfg: Any) -> DeviceBinding:
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
            duty_inputs={a.signal: DutyInput(a.duty_channel, a.duty_scale, a.signed, a.unit)
                         for a in ports.actuators},
            constant_inputs=dict(ports.constants),
            encoder_signal=enc.wire.signal if enc and enc.wire else None,
            encoder_counts_per_rev=int(enc.counts_per_unit) if enc else 0,
            adc=adc, step_s=step_s, substeps=substeps,
            encoder_source=source(enc) if enc else "", plant=cls.name, angle_output=enc.signal if enc else "",
            encoder_direction=int(getattr(getattr(cfg, "encoder", None), "direction", 1)),
            sums=ports.sums,
        )


def compose(plant: type[Plant], cfg: Any) -> list[Part]:
    """The plant's parts plus the config's ``[[effects]]``: the one place effects are added, for
    simulation, replay and the simulated rig alike. Every effect acts from the start and
    ``[[changes]]`` are not applied: their schedule is the simulated rig's (``Plant.device``)."""
    parts = plant.build(cfg)
    effects = [(e.name, e.params) for e in getattr(cfg, "effects", ())]
    if not effects:
        return parts
    return attach(plant.name, plant.ports(cfg), plant.step(cfg)[0], parts, effects)


# --- changes during a session ---------------------------------------------------------------

# the shared tables: not the plant's model, so no [[changes]] key points into them
NOT_CHANGEABLE = ("plant", "simulation", "rig", "effects", "changes", "controllers", "recorded_controller", "import",
                  "twin")


def scheduled(cfg: Any) -> bool:
    """Whether ``cfg`` schedules anything mid-session (an effect with start_s or ramp_s, a change)."""
    return bool(getattr(cfg, "changes", ())) or any(e.timing.scheduled for e in getattr(cfg, "effects", ()))


def changeable_keys(cfg: Any) -> dict[str, Any]:
    """Every leaf of the plant's own tables by dotted TOML key -> its value (what a change may name)."""
    out: dict[str, Any] = {}

    def walk(obj: Any, prefix: str) -> None:
        if isinstance(obj, BaseModel):
            for name, f in type(obj).model_fields.items():
                walk(getattr(obj, name), prefix + (f.alias or name) + ".")
        elif isinstance(obj, dict):
            for k, v in obj.items():
                walk(v, f"{prefix}{k}.")
        else:
            out[prefix[:-1]] = obj

    for name, f in type(cfg).model_fields.items():
        if (f.alias or name) not in NOT_CHANGEABLE:
            walk(getattr(cfg, name), (f.alias or name) + ".")
    return out


def _replaced(obj: Any, parts: Sequence[str], value: float) -> Any:
    """``obj`` with the dotted key ``parts`` set to ``value``, every table on the way validated again."""
    head, rest = parts[0], parts[1:]
    if isinstance(obj, dict):
        return {**obj, head: value if not rest else _replaced(obj[head], rest, value)}
    fields = {(f.alias or k): k for k, f in type(obj).model_fields.items()}
    data = {a: getattr(obj, k) for a, k in fields.items()}
    data[head] = value if not rest else _replaced(data[head], rest, value)
    return type(obj).model_validate(data)


def with_change(cfg: Any, i: int) -> Any:
    """``cfg`` with its change ``i`` (``[[changes]]`` entry) at its end value; ScheduleError names the
    entry's key when the key is unknown, not a real number, or its new value is refused."""
    ch = cfg.changes[i]
    known = changeable_keys(cfg)
    where = f"changes.{i}.key"
    if ch.key.split(".")[0] in NOT_CHANGEABLE:
        raise ScheduleError(where, f"{ch.key!r} is in a shared table ({ch.key.split('.')[0]}), not the plant's "
                            "model; a change names a key of the plant's own tables")
    if ch.key not in known:
        near = difflib.get_close_matches(ch.key, [k for k, v in known.items() if type(v) is float], n=1)
        hint = f" (did you mean {near[0]!r}?)" if near else ""
        raise ScheduleError(where, f"unknown key {ch.key!r}{hint}")
    old = known[ch.key]
    if type(old) is not float:
        raise ScheduleError(where, f"{ch.key} is {old!r}, not a real number: only real-valued keys can change")
    new = ch.value if ch.value is not None else old * ch.scale
    try:
        return _replaced(cfg, ch.key.split("."), new)
    except ValidationError as e:
        err = e.errors()[0]
        raise ScheduleError(f"changes.{i}.{'value' if ch.value is not None else 'scale'}",
                            f"{ch.key} = {new:g} is refused: {err['msg'].lower()}") from None


def _scheduled_binding(plant: type[Plant], cfg: Any) -> DeviceBinding:
    """The rig binding at the session's start (scheduled effects off, changed keys at their config
    values) with the schedule that moves them to their end values."""
    eff = [i for i, e in enumerate(cfg.effects) if e.timing.scheduled]
    n_ch = len(cfg.changes)
    keys = [f"effects.{i}" for i in eff] + [f"changes.{j}.key" for j in range(n_ch)]
    timings = [cfg.effects[i].timing for i in eff] + [c.timing for c in cfg.changes]
    ends_cfg = [with_change(cfg, j) for j in range(n_ch)]

    def off(e: EffectSpec) -> EffectSpec:
        full = check_spec(e.name, e.params)
        return e.model_copy(update={"params": {p.name: (p.off if p.off is not None else full[p.name])
                                               for p in EFFECTS[e.name].params}})

    def binding_with(ends: frozenset[int]) -> DeviceBinding:
        c = cfg
        for j in range(n_ch):
            if len(eff) + j in ends:
                c = ends_cfg[j]  # one item at its end value at a time (build_schedule asks for no more)
        effects = [off(e) if i in eff and eff.index(i) not in ends else e for i, e in enumerate(cfg.effects)]
        return plant._binding(c.model_copy(update={"effects": effects, "changes": []}))

    schedule = build_schedule(keys, timings, binding_with)
    binding = binding_with(frozenset())
    binding.schedule = schedule
    return binding


def plants() -> dict[str, type[Plant]]:
    """Every registered plant; the first call imports each module of ``rehab_hil.plants``."""
    if not getattr(plants, "_scanned", False):
        pkg = importlib.import_module("rehab_hil.plants")
        for mod in pkgutil.iter_modules(pkg.__path__):
            if not mod.name.startswith("_") and mod.name != "base":
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


def run_scenario(spec: type[Plant], cfg: Any, scenario: Scenario,
                 extra_parts: list[Part] | None = None) -> SimulationResult:
    """Compile plant + scenario (+ extra effect parts) and simulate; records CSV signals."""
    diagram = spec.diagram(cfg, [*(extra_parts or []), *scenario.parts], extra_inputs=scenario.inputs,
                           extra_sums=scenario.sums)
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

