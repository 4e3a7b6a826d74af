"""Controllers declared like plants: a small diagram of parts from state interfaces to a command interface.

A controller module declares one ``ControllerSpec``: its name (the ``[controllers.<name>]`` table
and ``[rig.session] controller``), its settings schema, what it needs of a plant, and ``build``,
which returns the controller's parts for one plant config and one reference. The parts read the
rig's state interfaces by the plant's own signal names (the encoder angle ``theta_mcp_deg``, the
axis velocity, the ADC channels) and the sample interval ``dt_s``; they write the plant's actuator
input (``pwm_duty``, ``power_w``, ``motor_voltage_v``) and the reference it tracked. So the same
parts compose with the plant model in one diagram offline (``closed_loop``) and run alone on the
rig, stepped by the loop with dt from device time (``loop/controllers.py``). Claims are
derived from the parts' inputs and outputs, never typed. In the spirit of ros2_control's
chainable controllers: reference -> feedforward + feedback -> limits -> actuator.
"""

from __future__ import annotations

import difflib
import importlib
import math
import pkgutil
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field, replace
from typing import Any, ClassVar, Literal

import numpy as np

from rehab_hil.config import ConfigError, Section
from rehab_hil.control.trajectories import OpenCloseReference, StepReference, open_close_reference
from rehab_hil.interfaces import Claims, DeviceBinding
from rehab_hil.models.ports import Ports
from rehab_hil.models.system import Diagram, DiagramError, Part, SimulationResult
from rehab_hil.plants.registry import Plant, get_plant
from rehab_hil.plants.sections import PlantConfig
from rehab_hil.session_metrics import cycle_metrics, session_summary

__all__ = [
    "DT",
    "ControlContext",
    "Controller",
    "ControllerError",
    "ControllerSpec",
    "Plan",
    "Reference",
    "closed_loop",
    "controller_names",
    "controllers",
    "get_controller",
    "offline_session",
    "safety_temperature",
]

DT = "dt_s"  # the controller's input: device time since its last step [s]


class ControllerError(ValueError):
    """A controller cannot be built for this plant, config or reference."""


# --- the plant as a controller sees it --------------------------------------------------------


@dataclass(frozen=True)
class ControlContext:
    """One plant config from a controller's side: its ports, rig binding and the signal names."""

    cfg: PlantConfig
    plant: type[Plant]
    ports: Ports
    binding: DeviceBinding
    source: str = "<config>"  # the config's path, for messages

    @classmethod
    def of(cls, cfg: PlantConfig, source: str = "<config>") -> ControlContext:
        plant = get_plant(cfg.plant)
        return cls(cfg, plant, plant.ports(cfg), plant.device(cfg), source)

    @property
    def effort(self) -> str:
        """The actuator input the controller commands (its command interface)."""
        return self.ports.actuators[0].signal

    @property
    def signed(self) -> bool:
        return self.ports.actuators[0].signed

    @property
    def effort_bounds(self) -> tuple[float, float]:
        """The effort PWM can apply under the rig's ``max_duty`` [actuator unit]."""
        a = self.ports.actuators[0]
        hi = a.duty_scale * self.cfg.rig.limits.max_duty
        return (-hi if a.signed else 0.0), hi

    @property
    def angle(self) -> str:
        """The encoder angle in degrees (a plant output and the recorded column)."""
        return self.binding.angle_output

    @property
    def velocity(self) -> str:
        """The joint velocity [rad/s] (the axis's signal; on the rig the estimator's)."""
        return self.ports.axes[0].velocity if self.ports.axes else ""

    @property
    def reference(self) -> str:
        return self.binding.reference_column

    @property
    def analog(self) -> tuple[str, ...]:
        return tuple(ch.signal for ch in self.binding.adc)

    @property
    def state_signals(self) -> tuple[str, ...]:
        """The state interfaces a controller may read, by signal name."""
        enc = (self.angle, self.velocity) if self.binding.encoder_signal else ()
        return tuple(s for s in (*enc, *self.analog) if s)

    @property
    def step_s(self) -> float:
        return float(self.plant.step(self.cfg)[0])

    @property
    def period_s(self) -> float:
        return 1.0 / self.cfg.rig.sample_rate_hz

    @property
    def angle_limits_deg(self) -> tuple[float, float]:
        """The host's range of motion (the rig's limits inside the host margin) [deg]."""
        host = self.cfg.rig.host_limits()
        return host.min_angle_deg, host.max_angle_deg


# --- references -----------------------------------------------------------------------------


@dataclass(frozen=True)
class Reference:
    """What the controller tracks [deg of the encoder angle]: open-close cycles (``[rig.session]``:
    closed, a raised-cosine move open, hold, move back, hold) or a step to ``open_deg``
    (``--reference step``). A session starts at rest, in its closed hold."""

    kind: Literal["session", "step"]
    closed_deg: float
    open_deg: float
    move_s: float = 1.2
    hold_open_s: float = 4.8
    hold_closed_s: float = 4.8
    start_deg: float = 0.0  # a step starts here (the rest pose)

    @classmethod
    def session(cls, cfg: PlantConfig) -> Reference:
        s = cfg.rig.session
        period = 60.0 / s.cycles_per_minute
        move = s.move_fraction * period
        hold = 0.5 * (period - 2.0 * move)
        return cls("session", s.closed_deg, s.open_deg, move, hold, hold)

    @classmethod
    def step(cls, cfg: PlantConfig, target_deg: float | None = None, start_deg: float = 0.0) -> Reference:
        s = cfg.rig.session
        period = 60.0 / s.cycles_per_minute
        return cls("step", start_deg, s.step_deg if target_deg is None else target_deg, 0.0, period, 0.0,
                   start_deg)

    @property
    def period_s(self) -> float:
        """One open-close cycle [s] (a step: its horizon, one session cycle)."""
        return 2.0 * self.move_s + self.hold_open_s + self.hold_closed_s

    @property
    def first_open_s(self) -> float:
        """When the first opening move starts: a session begins at rest, in its closed hold, so an
        actuator that lags (a wire heating from ambient) can start the bend on time [s]."""
        return self.hold_closed_s if self.kind == "session" else 0.0

    def part(self, signal: str) -> Part:
        """The reference as the head of the controller's chain."""
        if self.kind == "step":
            return StepReference("reference", rename={"reference": signal}, start=self.start_deg,
                                 target=self.open_deg, t_step_s=0.0)
        return OpenCloseReference("reference", rename={"reference": signal}, closed=self.closed_deg,
                                  opened=self.open_deg, move_s=self.move_s, hold_open_s=self.hold_open_s,
                                  hold_closed_s=self.hold_closed_s, offset_s=self.period_s - self.first_open_s)

    def values(self, t_s: np.ndarray) -> np.ndarray:
        """The reference at times ``t_s`` [deg] (as the part computes it)."""
        if self.kind == "step":
            return np.where(np.asarray(t_s) >= 0.0, self.open_deg, self.start_deg)
        offset = self.period_s - self.first_open_s
        return np.array([open_close_reference(float(t) + offset, self.closed_deg, self.open_deg, self.move_s,
                                              self.hold_open_s, self.hold_closed_s) for t in t_s])

    def clipped(self, lo: float, hi: float) -> tuple[Reference, str | None]:
        """This reference inside [lo, hi] deg, and a warning if it had to move."""
        keys = ("closed_deg", "open_deg") if self.kind == "session" else ("open_deg",)
        new = {k: min(max(getattr(self, k), lo), hi) for k in keys}
        moved = {k: v for k, v in new.items() if not math.isclose(v, getattr(self, k))}
        if not moved:
            return self, None
        what = ", ".join(f"{k} {getattr(self, k):g} -> {v:.3g}" for k, v in moved.items())
        return replace(self, **new), (f"the reference leaves what the model can reach ({lo:.3g}..{hi:.3g} deg): "
                                      f"clipped ({what})")


# --- plans: feedforward tables computed from the model --------------------------------------


@dataclass(frozen=True)
class Plan:
    """Signals a controller reads from a table by time (a feedforward computed on the model).

    ``signals`` hold one value per step of ``step_s`` over the horizon; after the horizon the
    last ``period_s`` repeats (a periodic reference's steady state). ``predicted`` are the
    model's outputs along the plan (angle, temperature) and ``figures`` what the planner found."""

    step_s: float
    period_s: float
    signals: Mapping[str, np.ndarray]
    predicted: Mapping[str, np.ndarray] = field(default_factory=dict)
    figures: Mapping[str, float] = field(default_factory=dict)
    key: str = ""  # the fingerprint of what the plan was learned from (a table learned on the rig belongs to it)

    @property
    def n(self) -> int:
        return len(next(iter(self.signals.values())))

    @property
    def _per(self) -> int:
        return max(1, min(self.n, round(self.period_s / self.step_s)))

    def index(self, t_s: float) -> int:
        """The table row for time ``t_s`` (nearest step; past the end, the last period again)."""
        k = max(int(t_s / self.step_s + 0.5), 0)
        n = self.n
        return k if k < n else n - self._per + (k - n) % self._per

    def arrays(self, n_steps: int) -> dict[str, np.ndarray]:
        """Each signal over ``n_steps`` steps of ``step_s`` from t = 0 (the offline input)."""
        k, n = np.arange(n_steps), self.n
        idx = np.where(k < n, k, n - self._per + (k - n) % self._per)
        return {name: np.asarray(v)[idx] for name, v in self.signals.items()}


# --- the built controller -------------------------------------------------------------------


@dataclass
class Controller:
    """One controller built for one plant and one reference: parts, the plan tables they read,
    constants (plant inputs the config holds, e.g. the supply voltage an observer needs) and
    the signals it sums (the effort demand of feedforward and feedback)."""

    name: str
    ctx: ControlContext
    reference: Reference
    parts: list[Part]
    plan: Plan | None = None
    constants: Mapping[str, float] = field(default_factory=dict)
    sums: tuple[str, ...] = ()
    notes: list[str] = field(default_factory=list)  # warnings for the operator (a clipped reference)
    rig_learning: Any = None  # how the plan keeps learning on the rig (controllers.rig_learning.RigLearningSpec)
    baseline: Any = None  # the same chain at full assistance, nothing learned (the assistance ratio's denominator)

    def __post_init__(self) -> None:
        # an entry may be a list of parts (``limit_part``: the heating guard and the effort limit)
        self.parts = [q for p in self.parts for q in (p if isinstance(p, list | tuple) else [p])]
        self._diagram = self._build_diagram()

    @property
    def plan_signals(self) -> tuple[str, ...]:
        return tuple(self.plan.signals) if self.plan else ()

    def _build_diagram(self) -> Diagram:
        ctx = self.ctx
        allowed = (*ctx.state_signals, DT, *self.plan_signals, *self.constants)
        try:
            d = Diagram(self.parts, inputs=allowed, sums=self.sums)
        except DiagramError as e:
            raise ControllerError(f"controller {self.name!r} on plant {ctx.cfg.plant!r}: {e} (state interfaces: "
                                  f"{', '.join(ctx.state_signals)})") from None
        for out in (ctx.effort, ctx.reference):
            if out not in d.producers:
                raise ControllerError(f"controller {self.name!r} writes no {out!r} (its outputs: "
                                      f"{', '.join(d.signal_names)})")
        return d

    @property
    def diagram(self) -> Diagram:
        """The controller alone: what the rig's loop steps."""
        return self._diagram

    @property
    def inputs(self) -> tuple[str, ...]:
        """The external signals the controller reads."""
        return self._diagram.input_names

    def offline_inputs(self, n_steps: int) -> dict[str, Any]:
        """What the controller reads beside the plant's outputs offline: dt, plan tables, constants."""
        given: dict[str, Any] = {**self.constants, DT: self.ctx.step_s}
        if self.plan is not None:
            given.update(self.plan.arrays(n_steps))
        return given

    @property
    def claims(self) -> Claims:
        """Derived from the parts: the effort it writes, the state interfaces it reads."""
        b = self.ctx.binding
        states: list[str] = []
        for s in self.inputs:
            if s in (self.ctx.angle, self.ctx.velocity) and b.encoder_signal:
                states.append(b.encoder_signal)
            elif s in self.ctx.analog:
                states.append(s)
        return Claims(command=(self.ctx.effort,), state=tuple(dict.fromkeys(states)))


def closed_loop(controller: Controller, duration_s: float, *, params: Mapping[str, float] | None = None,
                inputs: Mapping[str, np.ndarray | float] | None = None, outputs: Sequence[str] = (),
                plant_cfg: PlantConfig | None = None) -> SimulationResult:
    """The controller composed with its plant model (the config's ``[[effects]]`` included) in one
    diagram, simulated for ``duration_s`` from rest: the offline twin of a session. ``plant_cfg``
    puts another config's plant under it (the same plant with effects the controller's model lacks,
    as ``--sim-plant`` does on a simulated rig). ``inputs`` overrides plan tables or plant inputs
    (arrays per step); ``params`` sets ``"part.param"``."""
    system, feed = closed_loop_system(controller, plant_cfg)
    n = controller.ctx.plant.n_steps(controller.ctx.cfg, duration_s)
    given = {**feed(n), **(inputs or {})}
    p = system.params.copy()
    for key, value in (params or {}).items():
        p[system.diagram.param_index(key)] = value
    ctx = controller.ctx
    record = [*dict.fromkeys([ctx.angle, ctx.reference, ctx.effort, *outputs])]
    return system.simulate(n, {k: v for k, v in given.items() if k in system.input_names}, outputs=record, params=p)


def closed_loop_system(controller: Controller, plant_cfg: PlantConfig | None = None
                       ) -> tuple[Any, Callable[[int], dict[str, Any]]]:
    """The compiled plant + controller diagram and a function giving its inputs for ``n`` steps."""
    ctx = controller.ctx
    cfg = ctx.cfg if plant_cfg is None else plant_cfg
    if cfg.plant != ctx.cfg.plant:
        raise ControllerError(f"a {ctx.cfg.plant!r} controller cannot drive a {cfg.plant!r} plant")
    diagram = ctx.plant.diagram(cfg, controller.parts, extra_inputs=(DT, *controller.plan_signals,
                                                                      *controller.constants),
                                extra_sums=controller.sums)
    step_s, substeps = ctx.plant.step(cfg)
    system = diagram.compile(step_s, substeps)
    constants = ctx.plant.ports(cfg).constants

    def feed(n: int) -> dict[str, Any]:
        return {**constants, **controller.offline_inputs(n)}

    return system, feed


def safety_temperature(cfg: PlantConfig, effort: np.ndarray, duty_scale: float, step_s: float,
                       max_duty: float = 1.0) -> np.ndarray | None:
    """The safety's estimate (``plants.thermal.safety_thermal``) over a run of ``effort`` per step, as the
    supervisor computes it on the rig from the duty sent (clamped to ``max_duty``); None without one."""
    from rehab_hil.plants.thermal import safety_thermal

    est = safety_thermal(cfg)
    if est is None:
        return None
    duty = np.minimum(np.abs(np.asarray(effort, float)) / duty_scale, max_duty)
    return np.array([est.step(d, step_s) for d in duty])


def offline_session(controller: Controller, cycles: int = 3, plant_cfg: PlantConfig | None = None,
                    outputs: Sequence[str] = ()) -> tuple[SimulationResult, dict[str, float]]:
    """``cycles`` open-close cycles of the controller on the model (after its rest at closed) and
    the per-cycle figures of all but the first (from rest), as a session reports them."""
    ref, ctx = controller.reference, controller.ctx
    cfg = ctx.cfg if plant_cfg is None else plant_cfg
    res = closed_loop(controller, ref.first_open_s + cycles * ref.period_s, plant_cfg=plant_cfg, outputs=outputs)
    effort = res[ctx.effort]
    power = ctx.plant.actuator_power_w(cfg, effort, np.zeros_like(effort))
    temp = safety_temperature(cfg, effort, ctx.ports.actuators[0].duty_scale, ctx.step_s)
    found = cycle_metrics(res.t - ref.first_open_s, res[ctx.reference], res[ctx.angle], power, temp, ref.period_s,
                          ref.move_s, ref.closed_deg, ref.open_deg)
    return res, session_summary(found[1:] if len(found) > 1 else found)


# --- declarations and their registry --------------------------------------------------------

_REGISTRY: dict[str, type[ControllerSpec]] = {}


class ControllerSpec:
    """One controller kind: its name, settings schema (``[controllers.<name>]``), what it needs of
    a plant (``refuse``) and how it builds its parts (``build``). Setting ``name`` registers it."""

    name: ClassVar[str]
    summary: ClassVar[str] = ""
    settings: ClassVar[type[Section] | None] = None

    def __init_subclass__(cls, **kwargs: Any) -> None:
        super().__init_subclass__(**kwargs)
        if "name" in cls.__dict__:
            _REGISTRY[cls.name] = cls

    @classmethod
    def refuse(cls, ctx: ControlContext) -> str | None:
        """Why this controller cannot drive this plant (None: it can)."""
        return None

    @classmethod
    def build(cls, ctx: ControlContext, settings: Any, reference: Reference) -> Controller:
        raise NotImplementedError


def controllers() -> dict[str, type[ControllerSpec]]:
    """Every registered controller; the first call imports each module of ``rehab_hil.controllers``."""
    if not getattr(controllers, "_scanned", False):
        pkg = importlib.import_module("rehab_hil.controllers")
        for mod in pkgutil.iter_modules(pkg.__path__):
            if not mod.name.startswith("_") and mod.name not in _NOT_CONTROLLERS:
                importlib.import_module(f"rehab_hil.controllers.{mod.name}")
        controllers._scanned = True  # type: ignore[attr-defined]
    return _REGISTRY


_NOT_CONTROLLERS = {"base", "feedforward", "observer", "reachable", "build", "tuning"}


def controller_names() -> list[str]:
    return sorted(controllers())


def get_controller(name: str, source: str = "<config>", key: str = "rig.session.controller") -> type[ControllerSpec]:
    known = controllers()
    if name not in known:
        near = difflib.get_close_matches(name, known, n=1)
        hint = f" (did you mean {near[0]!r}?)" if near else ""
        raise ConfigError(source, key, f"unknown controller {name!r}{hint}; known: {sorted(known)}")
    return known[name]
