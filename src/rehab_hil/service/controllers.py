"""Controllers of the real-time loop: open-loop PWM profile, PID on the encoder angle (seed 002),
PWM-ratio control of SMA bending (seed 000 Fig. 10) and open-close rehabilitation sessions.

A controller maps (time, ``State``) to a ``Command`` of PWM duties and direction bits. It knows the
plant's I/O binding (which PWM channel drives which plant input) but never the device backend, and
declares the interfaces it uses in ``claims`` (checked by ``rehab_hil.hardware.contract.on_configure``).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import Protocol

from rehab_hil.control.pid import PID
from rehab_hil.control.trajectories import open_close_reference
from rehab_hil.hardware.contract import Claims
from rehab_hil.plants.base import DeviceBinding, DutyInput
from rehab_hil.service.estimation import State

__all__ = [
    "SAFE_COMMAND",
    "Actuator",
    "Command",
    "Controller",
    "OpenLoopPWM",
    "PIDPosition",
    "PWMRatio",
    "constant_reference",
    "cycle_reference",
]

Reference = Callable[[float], float]  # time [s] -> reference angle [deg]


@dataclass(frozen=True)
class Command:
    """Duties per PWM channel (0..1), direction bits (bit i: channel i reversed), enable, and the
    reference the controller tracked (deg, nan if none) for the recording."""

    duty: tuple[float, float] = (0.0, 0.0)
    direction: int = 0
    enable: bool = False
    reference_deg: float = math.nan


SAFE_COMMAND = Command()


class Controller(Protocol):
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
        self.input: DutyInput = binding.duty_inputs[self.signal]
        # the encoder angle a feedback controller reads ("angle" when the binding has none: refused)
        self.angle_signal: str = binding.encoder_signal or "angle"

    @property
    def max_effort(self) -> float:
        return self.input.scale

    @property
    def min_effort(self) -> float:
        return -self.input.scale if self.input.signed else 0.0

    def command(self, effort: float, reference_deg: float = math.nan) -> Command:
        u = effort if self.input.signed else max(effort, 0.0)
        return self.duty_command(min(abs(u) / self.input.scale, 1.0), u < 0.0, reference_deg)

    def duty_command(self, duty: float, reverse: bool = False, reference_deg: float = math.nan) -> Command:
        ch = self.input.channel
        duties = [0.0, 0.0]
        duties[ch] = min(max(duty, 0.0), 1.0)
        return Command((duties[0], duties[1]), (1 << ch) if reverse else 0, True, reference_deg)


def constant_reference(angle_deg: float) -> Reference:
    return lambda t: angle_deg


def cycle_reference(closed_deg: float, open_deg: float, cycles_per_minute: float,
                    move_fraction: float) -> Reference:
    """Open-close cycles at ``cycles_per_minute`` (seed 000: 5); each move takes ``move_fraction``
    of a cycle, the rest is split between holding open and holding closed."""
    period = 60.0 / cycles_per_minute
    move = move_fraction * period
    hold = 0.5 * (period - 2.0 * move)
    return lambda t: open_close_reference(t, closed_deg, open_deg, move, hold, hold)


class OpenLoopPWM:
    """A repeating duty profile: ``on_duty`` for ``on_s``, then 0 for ``off_s``. On a signed
    (H-bridge) input every other push runs reversed, so a motor goes out and back."""

    def __init__(self, actuator: Actuator, on_duty: float, on_s: float, off_s: float) -> None:
        self.actuator, self.on_duty, self.on_s, self.period = actuator, on_duty, on_s, on_s + off_s
        self.claims = Claims(command=(actuator.signal,))

    def reset(self) -> None:
        pass

    def __call__(self, t_s: float, state: State) -> Command:
        n, tc = divmod(t_s, self.period)
        reverse = self.actuator.input.signed and int(n) % 2 == 1
        return self.actuator.duty_command(self.on_duty if tc < self.on_s else 0.0, reverse)


class PIDPosition:
    """PID on the encoder angle in degrees (the shared ``pid_step``); the output is the effort on
    the actuator's plant input (volts for the Finger Extensor), clamped to what PWM can apply."""

    def __init__(self, actuator: Actuator, reference: Reference, kp: float, ki: float, kd: float,
                 derivative_filter_s: float, dt_s: float) -> None:
        self.actuator, self.reference = actuator, reference
        self.claims = Claims(command=(actuator.signal,), state=(actuator.angle_signal,))
        self.pid = PID(kp, ki, kd, derivative_filter_s, actuator.min_effort, actuator.max_effort, dt_s)

    def reset(self) -> None:
        self.pid.reset()

    def __call__(self, t_s: float, state: State) -> Command:
        ref = self.reference(t_s)
        return self.actuator.command(self.pid(ref, state.angle_deg), ref)


class PWMRatio:
    """Open-loop PWM-ratio control of SMA bending (seed 000 sec B, Fig. 10): at thermal equilibrium
    the bending angle rises about linearly with the PWM ratio between ``duty_min`` (0.4) and
    ``duty_max`` (1.0). A reference at or below the angle reached at ``duty_min`` gets duty 0
    (the wire cools and the finger returns)."""

    def __init__(self, actuator: Actuator, reference: Reference, duty_min: float, duty_max: float,
                 angle_at_duty_min_deg: float, angle_at_duty_max_deg: float) -> None:
        if not angle_at_duty_max_deg > angle_at_duty_min_deg:
            raise ValueError("angle_at_duty_max_deg must exceed angle_at_duty_min_deg")
        self.actuator, self.reference = actuator, reference
        self.claims = Claims(command=(actuator.signal,))  # open loop: no state read
        self.d0, self.d1 = duty_min, duty_max
        self.a0, self.a1 = angle_at_duty_min_deg, angle_at_duty_max_deg

    def reset(self) -> None:
        pass

    def duty_for(self, angle_deg: float) -> float:
        if angle_deg <= self.a0:
            return 0.0
        frac = min((angle_deg - self.a0) / (self.a1 - self.a0), 1.0)
        return self.d0 + (self.d1 - self.d0) * frac

    def __call__(self, t_s: float, state: State) -> Command:
        ref = self.reference(t_s)
        return self.actuator.duty_command(self.duty_for(ref), False, ref)
