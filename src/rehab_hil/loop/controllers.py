"""The loop's side of a controller: the command it sends and the runtime that steps a built controller.

Controllers themselves are declared in ``rehab_hil.controllers`` (parts from state interfaces to a
command interface, the same for simulation and the rig): ``Controller`` names that declaration.
Here ``LoopController`` is what the loop steps (claims, reset, a command per sample),
``ControllerRuntime`` is the one that steps a declared controller in the real-time loop with dt
from device time, and ``Actuator`` turns its effort on the plant's
actuator input into a PWM duty and direction bit (the command interface's conversion), so a
controller never knows the device backend.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from types import ModuleType
from typing import Any, Protocol

import numpy as np

from rehab_hil.controllers.base import DT, Controller, Reference
from rehab_hil.controllers.observer import OBSERVER
from rehab_hil.interfaces import Claims, CommandInterface, DeviceBinding
from rehab_hil.loop.estimation import State
from rehab_hil.loop.thermal import ObserverFollow

__all__ = ["SAFE_COMMAND", "Actuator", "Command", "ControllerRuntime", "LoopController"]


@dataclass(frozen=True)
class Command:
    """Duties per PWM channel (0..1), direction bits (bit i: channel i reversed), enable, and the
    reference the controller tracked (deg, nan if none) for the recording."""

    duty: tuple[float, float] = (0.0, 0.0)
    direction: int = 0
    enable: bool = False
    reference_deg: float = math.nan


SAFE_COMMAND = Command()


class LoopController(Protocol):
    """What the loop steps: a ``Command`` per sample (a ``ControllerRuntime``, or a test's own)."""

    claims: Claims  # the command and state interfaces it uses, by name

    def reset(self) -> None: ...

    def __call__(self, t_s: float, state: State) -> Command: ...


class Actuator:
    """Turns an effort on one plant input (e.g. ``motor_voltage_v``) into a duty and direction
    bit on its PWM channel: duty = |u| / scale, reversed when u < 0 on a signed (H-bridge) input."""

    def __init__(self, binding: DeviceBinding, signal: str | None = None) -> None:
        if not binding.duty_inputs:
            raise ValueError("the plant's device binding has no PWM-driven input")
        self.signal = signal or next(iter(binding.duty_inputs))
        self.input: CommandInterface = binding.duty_inputs[self.signal]
        # the encoder angle a feedback controller reads ("angle" when the binding has none: refused)
        self.angle_signal: str = binding.encoder_signal or "angle"

    @property
    def max_effort(self) -> float:
        return self.input.scale

    @property
    def min_effort(self) -> float:
        return -self.input.scale if self.input.signed else 0.0

    def command(self, effort: float, reference_deg: float = math.nan) -> Command:
        duty, reverse = self.input.duty(effort)
        return self.duty_command(duty, reverse, reference_deg)

    def effort(self, cmd: Command) -> float:
        """The effort a command applies on this actuator's input (the inverse of ``command``)."""
        return self.input.effort(cmd.duty[self.input.channel], cmd.direction) if cmd.enable else 0.0

    def duty_command(self, duty: float, reverse: bool = False, reference_deg: float = math.nan) -> Command:
        ch = self.input.channel
        duties = [0.0, 0.0]
        duties[ch] = min(max(duty, 0.0), 1.0)
        return Command((duties[0], duties[1]), (1 << ch) if reverse else 0, True, reference_deg)


def load_engine(diagram: Any, period_s: float) -> ModuleType:
    """The controller diagram's engine, its entry points compiled or loaded from the disk cache (a loop
    process's unpickled runtime, and the zygote that forks it: ``rehab_hil.launch``)."""
    return diagram.compile(period_s, 1).engine


class ControllerRuntime:
    """A built controller (``rehab_hil.controllers``) stepped by the loop: the state interfaces in,
    a ``Command`` out. dt is the device time since the last step (a loop behind a USB bridge
    controls once per burst of samples), so the PID integrates and differentiates over the time
    that passed. Continuous states (an observer) are advanced over that interval with the inputs
    of the previous step, the effort that was applied, before the new sample is taken; the loop
    calls ``advance`` once the command is out, so the usual one period of that integration is
    done while it waits for the next sample, not between the sample and the command. No
    allocation per step beyond the returned command."""

    def __init__(self, controller: Controller) -> None:
        ctx = controller.ctx
        self.controller = controller
        self.claims = controller.claims
        self.actuator = Actuator(ctx.binding, ctx.effort)
        system = controller.diagram.compile(ctx.period_s, 1)
        self._engine = system.engine
        self._params = system.params.copy()
        self._x0, self._xd0 = system.x0, system.xd0
        self._ws = system.workspace()
        saturation = f"{ctx.effort}_saturation"  # the effort limit's: demand the limit or a cut did not apply
        outs = [ctx.effort, ctx.reference, *([saturation] if saturation in controller.diagram.signal_names else [])]
        self._slots = system.out_slots(outs)
        self._y = np.zeros(3)
        names = system.input_names
        self._period = ctx.period_s
        self._i_angle = names.index(ctx.angle) if ctx.angle in names else -1
        self._i_velocity = names.index(ctx.velocity) if ctx.velocity in names else -1
        self._i_dt = names.index(DT) if DT in names else -1
        self._analog = [(names.index(s), s) for s in ctx.analog if s in names]
        plan = controller.plan
        self._plan = plan
        self._tables = [(names.index(s), np.asarray(v, float)) for s, v in (plan.signals.items() if plan else ())
                        if s in names]
        self._u = np.zeros(max(len(names), 1))
        for name, value in controller.constants.items():
            if name in names:
                self._u[names.index(name)] = value
        self._u_prev = self._u.copy()
        self._row = -1  # the plan row the last step read
        self._table_slot = -1  # the learned table's place in ``_tables`` (-1: none learned on the rig)
        self._offered: tuple[np.ndarray, tuple[np.ndarray, dict[str, float]] | None] | None = None
        self._follow: Any = None  # the observer follows the supervisor's temperature estimate (``follow_thermal``)
        self.swapped_at: list[float] = []  # device times an offered table was taken (a loop process's swaps)
        self.reset()

    def learn_on_rig(self, table: np.ndarray) -> None:
        """Read the learned feedforward from now on (``service/rig_learning.py``: a stored table when
        the rig and patient have learned before); later tables come through ``swap_table``."""
        plan = self._plan
        assert plan is not None and self._tables, "learning on the rig needs a plan table"
        names = self.controller.diagram.input_names
        slots = [j for j, (i, _) in enumerate(self._tables) if names[i] in plan.signals]
        self._table_slot = slots[0]
        self.swap_table(table)

    def swap_table(self, table: np.ndarray, retune: tuple[np.ndarray, dict[str, float]] | None = None) -> None:
        """A new learned table (and the re-planned controller's parameters with it), between two samples."""
        i, _ = self._tables[self._table_slot]
        self._tables[self._table_slot] = (i, np.asarray(table, float))
        if retune is not None:
            self.retune(*retune)

    def offer_table(self, table: np.ndarray, retune: tuple[np.ndarray, dict[str, float]] | None = None) -> None:
        """A table learned in the session's process while this runtime runs in a loop process: taken at
        the next swap window the controller names (``RigLearningSpec.swap_s`` to the end of the closed
        hold, where the table is idle), never in a move."""
        self._offered = (np.asarray(table, float), retune)

    def _take_offered(self, t_s: float) -> None:
        spec = self.controller.rig_learning
        phase = t_s % spec.period_s
        if spec.swap_s <= phase < 2.0 * spec.swap_s and self._offered is not None:
            self.swap_table(*self._offered)
            self._offered = None
            self.swapped_at.append(t_s)

    @property
    def learned_table(self) -> np.ndarray | None:
        """The learned table read now (None: no learning on the rig)."""
        return self._tables[self._table_slot][1] if self._table_slot >= 0 else None

    def last_step(self) -> tuple[int, float, float, float]:
        """What the last step computed, for the learning on the rig: (plan row, reference - angle [deg],
        effort, the demand the limit cut)."""
        y = self._y
        error = float(y[1]) - float(self._u_prev[self._i_angle]) if self._i_angle >= 0 else math.nan
        return self._row, error, float(y[0]), float(y[2])

    def follow_thermal(self, supervisor: Any) -> bool:
        """The observer and its ceiling take the supervisor's estimate each step (``loop.thermal.ObserverFollow``)."""
        self._follow = ObserverFollow.of(supervisor, self.controller.diagram, OBSERVER)
        return self._follow is not None

    def __getstate__(self) -> dict[str, object]:
        """Everything but the compiled engine (a loop process compiles it again from the diagram, a load from
        the on-disk cache) and the supervisor it follows (wired again there): it crosses as it is."""
        state = dict(self.__dict__)
        state.pop("_engine")
        state["_follow"] = None
        return state

    def __setstate__(self, state: dict[str, object]) -> None:
        self.__dict__.update(state)
        self._engine = load_engine(self.controller.diagram, self.controller.ctx.period_s)

    def adopt(self, other: ControllerRuntime) -> None:
        """Take the states, tables and parameters ``other`` ended with (the loop process's copy of this
        runtime, back after its run): a kept assistance reads them."""
        self._x, self._xd, self._params, self._tables = other._x, other._xd, other._params, other._tables
        self.swapped_at = list(other.swapped_at)

    def discrete_states(self, qualified: tuple[str, ...]) -> dict[str, float]:
        """The named discrete states now (``part.state``: an assistance learned in this session)."""
        names = self.controller.diagram.discrete_state_names
        return {q: float(self._xd[names.index(q)]) for q in qualified}

    def start_from(self, values: dict[str, float]) -> None:
        """Start with these discrete states instead of the declared ones (``part.state``: an
        assistance learned in an earlier session); before the loop runs."""
        names = self.controller.diagram.discrete_state_names
        xd0 = self._xd0.copy()
        for q, v in values.items():
            xd0[names.index(q)] = v
        self._xd0 = xd0
        self._xd = xd0.copy()

    def retune(self, params: np.ndarray, constants: dict[str, float]) -> None:
        """The same diagram with other parameter values and plant constants (the controller built
        again on a model updated by estimates: its thermal observer and ceiling), between two samples."""
        if np.shape(params) != np.shape(self._params):
            raise ValueError("a retune must come from the same controller's diagram")
        self._params = np.array(params, float)
        names = self.controller.diagram.input_names
        for name, value in constants.items():
            if name in names:
                self._u[names.index(name)] = self._u_prev[names.index(name)] = value

    @property
    def name(self) -> str:
        """The declared controller's name."""
        return self.controller.name

    @property
    def notes(self) -> list[str]:
        """The declared controller's warnings for the operator (a clipped reference)."""
        return self.controller.notes

    @property
    def reference(self) -> Reference:
        """What the declared controller tracks."""
        return self.controller.reference

    def reset(self) -> None:
        self._x = self._x0.copy()
        self._xd = self._xd0.copy()
        self._t_last: float | None = None
        self._ahead_s = 0.0  # of the interval after the last step, already integrated by ``advance``

    def advance(self) -> None:
        """After the command is out: integrate one period ahead with the effort just applied (the
        interval to the next sample, when none is lost), so the next call only takes the sample."""
        if self._offered is not None and self._t_last is not None:
            self._take_offered(self._t_last)
        if self._t_last is None or self._ahead_s:
            return
        sig, w, stage, _ = self._ws
        self._engine.integrate(self._t_last, self._x, self._xd, self._u_prev, self._params, self._period, 1, sig, w,
                               stage)
        self._ahead_s = self._period

    def __call__(self, t_s: float, state: State) -> Command:
        u, e = self._u, self._engine
        sig, w, stage, xdn = self._ws
        last = self._t_last
        dt = self._period if last is None or t_s <= last else t_s - last
        if last is not None and t_s > last + self._ahead_s + 1e-12:  # the interval just past (what ``advance``
            t0 = last + self._ahead_s  # left of it: samples lost or coalesced), with the effort applied
            e.integrate(t0, self._x, self._xd, self._u_prev, self._params, t_s - t0, 1, sig, w, stage)
        self._ahead_s = 0.0
        if self._i_angle >= 0:
            u[self._i_angle] = state.angle_deg
        if self._i_velocity >= 0:
            u[self._i_velocity] = state.velocity_rad_s
        for i, name in self._analog:
            u[i] = state.analog.get(name, 0.0)
        if self._i_dt >= 0:
            u[self._i_dt] = dt
        if self._tables:
            k = self._row = self._plan.index(t_s)
            for i, table in self._tables:
                u[i] = table[k]
        if self._follow is not None:
            self._follow(t_s, self._x)
        e.sample(t_s, self._x, self._xd, u, self._params, sig, w, xdn)
        e.read_outputs(self._slots, sig, self._y)
        self._u_prev[:] = u
        self._t_last = t_s
        return self.actuator.command(float(self._y[0]), float(self._y[1]))
