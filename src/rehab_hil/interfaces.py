"""The typed interface names of a rig, in the spirit of ros2_control's state and command interfaces.

Pure value types, shared by the plants (whose rig binding declares them) and the hardware layer
(whose contract checks them against the device, ``rehab_hil.hardware.contract``). This module
imports nothing of the rig, so a plant can describe its interfaces without pulling in the serial
link or the hardware implementations.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

__all__ = ["Claims", "CommandInterface", "Source", "StateInterface", "StateKind"]

StateKind = Literal["angle", "force", "torque", "temperature"]
Source = Literal["encoder", "adc0", "adc1"]


@dataclass(frozen=True)
class StateInterface:
    """A measured quantity: ``name`` is the model signal (SI unit, e.g. ``theta_mcp_rad``), also the
    recorded column; ``source`` is where the device reads it (encoder counts or an ADC channel)."""

    name: str
    kind: StateKind
    unit: str
    source: Source


@dataclass(frozen=True)
class CommandInterface:
    """A commanded model input (``motor_voltage_v``, ``pwm_duty``, ``power_w``) driven by PWM
    ``channel``: value = scale * duty, negated by the direction pin when ``signed`` (an H-bridge)."""

    name: str
    unit: str
    channel: int
    scale: float
    signed: bool = False


@dataclass(frozen=True)
class Claims:
    """The interfaces a controller uses, by name: command interfaces it writes, state interfaces
    it reads. ``rehab_hil.hardware.contract.on_configure`` refuses a claim the binding does not
    provide."""

    command: tuple[str, ...] = ()
    state: tuple[str, ...] = ()
