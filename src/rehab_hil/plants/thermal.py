"""Each heated actuator's one thermal model, declared by its plant.

A plant declares where its actuator's temperature is (``Ports.transformation_temperature``: the SMA
wire's, which its material law reads; ``Ports.heat``: the TCP coil's) and the parts that compute it
(seed 000 eq 12 for the SMA wire, seed 001's TF_TP002 for the TCP coil). The actuator's one thermal
model is the slice of the plant's composed model (its ``[[effects]]`` included) from the actuator's
input to that temperature (``thermal_slice``). Every temperature figure of a session comes from it:

- the safety's estimate, ``ActuatorThermal``: the slice compiled and advanced on the duty the rig applies
  (``safety_thermal``, ``loop/supervisor.py``), taking the twin's estimates only where they are stricter
  (``loop/thermal.py``);
- every controller's observer and ceiling: the same parts copied into its chain (``controllers/limits.py``),
  which on the rig follow the safety's state (``loop/controllers.py``);
- the twin: the whole model, whose thermal quantities it estimates (``twin/thermal.py``);
- a simulated rig's truth: the same model with the rig's own values, written to ``sim_truth.csv``.

A plant whose model has no heated actuator (the Finger Extensor: its winding's heat is not modelled)
keeps the host's own first-order estimate of ``[rig.thermal]`` (``control.thermal.ModalThermal``).
"""

from __future__ import annotations

import copy
import math
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

from rehab_hil.control.thermal import ModalThermal, thermal_from_config
from rehab_hil.models.ports import Ports
from rehab_hil.models.system import Diagram, Part
from rehab_hil.plants.registry import compose, get_plant

__all__ = ["ActuatorThermal", "actuator_thermal", "mechanical_signals", "safety_thermal", "steady_temperature_c",
           "temperature_signal", "thermal_slice"]


def temperature_signal(ports: Ports) -> str | None:
    """The actuator temperature the plant models (what its material law or heat port sees)."""
    if ports.transformation_temperature:
        return ports.transformation_temperature[0].wire.signal
    if ports.heat:
        return ports.heat[0].temperature
    return None


def mechanical_signals(ports: Ports) -> tuple[str, ...]:
    """The plant's joint signals (a thermal model from the effort alone must not depend on them)."""
    return tuple(s for ax in ports.axes for s in (ax.angle, ax.velocity, ax.torque))


def thermal_slice(parts: Sequence[Part], effort: str, temperature: str, constants: Mapping[str, float],
                  mechanical: Sequence[str] = (), prefix: str = "") -> list[Part] | None:
    """Copies of the parts that compute ``temperature`` from ``effort`` and ``constants`` only, their
    signals prefixed ``prefix`` (a controller's observer: ``observer_``); None when the temperature
    depends on anything else (an unknown input, or one of the ``mechanical`` signals: a joint's
    angle, velocity or torque) or on no state."""
    producers: dict[str, list[Part]] = {}
    for p in parts:
        for s in p.signal_names:
            producers.setdefault(s, []).append(p)
    needed: dict[str, Part] = {}
    todo = [temperature]
    seen: set[str] = set()
    while todo:
        sig = todo.pop()
        if sig in seen or sig == effort or sig in constants:
            continue
        seen.add(sig)
        if sig not in producers or sig in mechanical:
            return None  # not computable from the effort alone
        for p in producers[sig]:
            if p.name in needed:
                continue
            needed[p.name] = p
            for terms in p.connections.values():
                todo.extend(s for s, _ in terms)
    if not any(p.states for p in needed.values()):
        return None
    inside = {s for p in needed.values() for s in p.signal_names}
    out: list[Part] = []
    for p in parts:  # the plant's order
        if p.name not in needed:
            continue
        q = copy.deepcopy(p)
        q.name = prefix + p.name
        q.signal_names = tuple(prefix + s for s in p.signal_names)
        q.connections = {port: [((prefix + s) if s in inside else s, w) for s, w in terms]
                         for port, terms in p.connections.items()}
        out.append(q)
    return out


class ActuatorThermal:
    """The safety's estimate of a heated actuator's temperature [C]: the plant's thermal slice compiled
    at the plant's step and advanced, state by state, on the PWM duty the rig applies. It answers as
    ``control.thermal.ModalThermal`` does (``step``, ``temperature_c``, ``reset``), and ``retune`` takes
    the values of a stricter model (``loop/thermal.py``). It crosses to a loop process without its
    engine (compiled again there from the diagram: the on-disk cache makes that a load)."""

    def __init__(self, parts: Sequence[Part], effort: str, temperature: str, duty_scale: float,
                 constants: Mapping[str, float], step_s: float, sums: Sequence[str] = ()) -> None:
        self.effort, self.temperature, self.duty_scale, self.step_s = effort, temperature, duty_scale, step_s
        self.diagram = Diagram(list(parts), inputs=(effort, *constants), sums=sums)
        names = self.diagram.input_names
        self._u = np.zeros(max(len(names), 1))
        self._i_effort = names.index(effort) if effort in names else -1
        for name, value in constants.items():
            if name in names:
                self._u[names.index(name)] = value
        self._compile()
        self.params = self._system.params.copy()
        self.x0 = self._system.x0.copy()
        self.reset()

    def _compile(self) -> None:
        system = self._system = self.diagram.compile(self.step_s, 1)
        self._engine, self._ws = system.engine, system.workspace()
        self._slots, self._y = system.out_slots([self.temperature]), np.zeros(1)

    def __getstate__(self) -> dict[str, Any]:
        state = dict(self.__dict__)
        for key in ("_system", "_engine", "_ws", "_slots"):
            state.pop(key)
        return state

    def __setstate__(self, state: dict[str, Any]) -> None:
        self.__dict__.update(state)
        self._compile()

    @property
    def state_names(self) -> tuple[str, ...]:
        return self.diagram.state_names

    @property
    def constants(self) -> dict[str, float]:
        names = self.diagram.input_names
        return {n: float(self._u[i]) for i, n in enumerate(names) if i != self._i_effort}

    def reset(self) -> None:
        """At rest: the model's start state (the room's temperature)."""
        self.x = self.x0.copy()
        self._xd = self._system.xd0.copy()
        self._affine = self._affine_output()
        self.temperature_c = self._read()

    def _sampled(self) -> float:
        """The temperature output as the engine evaluates it (two compiled calls)."""
        sig, w, _, xdn = self._ws
        self._engine.sample(0.0, self.x, self._xd, self._u, self.params, sig, w, xdn)
        self._engine.read_outputs(self._slots, sig, self._y)
        return float(self._y[0])

    def _affine_output(self) -> tuple[float, list[float]] | None:
        """(y0, c) when the temperature is y0 + c . x whatever the effort (the SMA wire's is its state, the
        TCP coil's TF1 is C x + y0): then the loop reads it without the engine, a third of an estimate's
        cost. Found from the engine itself at the unit states and checked at two more; None otherwise."""
        keep, u_keep, n = self.x.copy(), self._u.copy(), self.x.size
        try:
            self.x[:] = 0.0
            y0 = self._sampled()
            c = []
            for i in range(n):
                self.x[:] = np.eye(n)[i]
                c.append(self._sampled() - y0)
            for probe, effort in ((np.linspace(20.0, 90.0, n), 0.0), (np.linspace(-3.0, 150.0, n), 1.0)):
                self.x[:] = probe
                if self._i_effort >= 0:
                    self._u[self._i_effort] = effort * self.duty_scale
                if abs(self._sampled() - (y0 + float(np.dot(c, probe)))) > 1e-9 * (1.0 + abs(y0)):
                    return None
            self._c = np.array(c)
            return y0, c
        finally:
            self.x[:], self._u[:] = keep, u_keep

    def _read(self) -> float:
        aff = self._affine
        if aff is None:
            return self._sampled()
        y0, c = aff
        if len(c) == 1:
            return y0 + c[0] * self.x.item(0)
        return y0 + float(self._c @ self.x)

    def step(self, duty: float, dt_s: float, substep_s: float | None = None) -> float:
        """Advance ``dt_s`` with ``duty`` held (RK4 at the plant's step or finer, or at ``substep_s``);
        return T [C]."""
        if dt_s > 0.0:
            if self._i_effort >= 0:
                self._u[self._i_effort] = (0.0 if duty <= 0.0 else 1.0 if duty >= 1.0 else duty) * self.duty_scale
            sig, w, stage, _ = self._ws
            n = max(1, math.ceil(dt_s / (substep_s or self.step_s) - 1e-9))
            self._engine.integrate(0.0, self.x, self._xd, self._u, self.params, dt_s, n, sig, w, stage)
            self.temperature_c = self._read()
        return self.temperature_c

    def retune(self, params: np.ndarray, constants: Mapping[str, float], duty_scale: float) -> None:
        """Another model of the same structure (``ActuatorThermal.of`` a config with other values):
        its parameters, plant constants and full-duty effort from now on; the state stays."""
        if np.shape(params) != np.shape(self.params):
            raise ValueError("a retune must come from the same thermal model's structure")
        self.params = np.array(params, float)
        names = self.diagram.input_names
        for name, value in constants.items():
            if name in names and names.index(name) != self._i_effort:
                self._u[names.index(name)] = value
        self.duty_scale = float(duty_scale)
        self._affine = self._affine_output()
        self.temperature_c = self._read()

    def set_state(self, x: np.ndarray) -> None:
        """Put the model in state ``x`` (a re-simulation's); the temperature follows."""
        self.x[:] = x
        self.temperature_c = self._read()

    def final_state(self, duty: np.ndarray) -> np.ndarray:
        """The state a run from rest reaches with ``duty`` per step of the plant's step (a fresh model's
        history, for what other values would have made of the same drive); this model is left as it is."""
        system = self._system
        U = np.tile(self._u, (len(duty), 1))
        if self._i_effort >= 0:
            U[:, self._i_effort] = np.clip(np.asarray(duty, float), 0.0, 1.0) * self.duty_scale
        x, xd = self.x0.copy(), system.xd0.copy()
        if len(duty):
            system.run_arrays(x, xd, U, self.params, self._slots, system.workspace())
        return x

    @classmethod
    def of(cls, cfg: Any) -> ActuatorThermal | None:
        """The thermal model of ``cfg``'s plant (its actuator's slice), or None where the plant models none."""
        plant = get_plant(cfg.plant)
        ports = plant.ports(cfg)
        temp = temperature_signal(ports)
        if temp is None or not ports.actuators:
            return None
        actuator = ports.actuators[0]
        parts = thermal_slice(compose(plant, cfg), actuator.signal, temp, ports.constants, mechanical_signals(ports))
        if parts is None:
            return None
        read = {s for p in parts for terms in p.connections.values() for s, _ in terms}
        constants = {k: v for k, v in ports.constants.items() if k in read}
        return cls(parts, actuator.signal, temp, actuator.duty_scale, constants, plant.step(cfg)[0], ports.sums)


def actuator_thermal(cfg: Any) -> ActuatorThermal | None:
    """``ActuatorThermal.of(cfg)``: the plant's thermal model of its actuator, or None."""
    return ActuatorThermal.of(cfg)


def safety_thermal(cfg: Any) -> ActuatorThermal | ModalThermal | None:
    """The safety's temperature estimate for ``cfg``: the plant's thermal model of its actuator, else the
    host's own ``[rig.thermal]`` estimate (a plant whose model has no heated actuator), else None."""
    model = ActuatorThermal.of(cfg)
    if model is not None:
        return model
    th = cfg.rig.thermal
    return thermal_from_config(th) if th is not None and th.rise_at_full_duty_c is not None else None


STEADY_SUBSTEP_S = 0.01  # RK4 step of the steady state's run [s]: 65x inside the fastest thermal mode modelled
#                          (the SMA wire's 0.65 s at 134 C, seed 000 eq 12), where the loop's step is 1 ms


def steady_temperature_c(model: ActuatorThermal | ModalThermal, duty: float, hold_s: float = 3600.0) -> float:
    """The temperature the estimate levels off at with ``duty`` held [C] (from rest, in 1 s steps until it
    moves less than 1 mC per step, at most ``hold_s``); the model is reset after."""
    model.reset()
    last = model.temperature_c
    coarse = {"substep_s": STEADY_SUBSTEP_S} if isinstance(model, ActuatorThermal) else {}
    try:
        for _ in range(int(hold_s)):
            now = model.step(duty, 1.0, **coarse)
            if abs(now - last) < 1e-3:
                return now
            last = now
        return last
    finally:
        model.reset()
