"""Typed ports of a plant: what an effect, a rig or a workflow may attach to, by kind.

A plant declares its ports once (``Plant.ports(cfg)``): the actuator input(s), the joint axes
(angle, velocity, the signal its torques are summed on), the measured signals with their sensor,
heat inputs and the temperature an SMA's material law sees, the inputs the config holds
constant, and the signals several of its parts sum onto. Effects name the port kind they need
(``rehab_hil.effects``), the rig binding is derived from the actuator and measured ports, and the
discrepancy workflow reads the measured kinds: nothing outside the plant module needs its part or
signal names.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Literal

__all__ = ["PORT_KINDS", "ActuatorPort", "AxisPort", "HeatPort", "MeasuredPort", "PortKind", "Ports", "TemperatureWire",
           "Wire"]

PortKind = Literal["actuator", "axis", "finger_axis", "encoder", "adc", "heat", "transformation_temperature"]
PORT_KINDS: tuple[str, ...] = ("actuator", "axis", "finger_axis", "encoder", "adc", "heat",
                               "transformation_temperature")
MeasuredKind = Literal["angle", "position", "velocity", "force", "torque", "temperature", "current", "voltage"]


@dataclass(frozen=True)
class Wire:
    """A signal as read by chosen consumers ((part, input port) pairs): a part inserted on the wire
    (a delay, a backlash) rewires exactly those consumers and no other reader of the signal."""

    signal: str
    consumers: tuple[tuple[str, str], ...]


@dataclass(frozen=True)
class ActuatorPort:
    """An actuator input (``motor_voltage_v``, ``pwm_duty``, ``power_w``) and the rig's PWM channel
    that drives it: value = duty_scale * duty, negated by the direction pin when ``signed``."""

    wire: Wire
    unit: str
    duty_channel: int = 0
    duty_scale: float = 1.0
    signed: bool = False

    @property
    def signal(self) -> str:
        return self.wire.signal


@dataclass(frozen=True)
class AxisPort:
    """A joint axis: its angle and velocity signals, the signal its torques are summed on, and the
    (part, port) that integrates the net torque (an effect that must read the net torque, like
    stiction, sums into that port instead of onto ``torque``).

    ``stick_*`` set the stick band of friction added to this axis; ``typical`` gives this axis's
    typical effect magnitudes (``"effect.param"`` -> value): a finger joint's torques are
    milli-newton-metres where the Finger Extensor's are tenths."""

    name: str
    angle: str
    velocity: str
    torque: str
    applied: tuple[str, str]
    finger: bool = False
    stick_velocity_rad_s: float = 0.01
    stick_damping_nm_s_per_rad: float = 0.0
    typical: Mapping[str, float] = field(default_factory=dict)
    # force-valued effect parameters (``EffectParam.axis_scaled``: friction, loads, contact) scale their
    # bounds and typical value by this: 1 for a finger joint (N m), the peak drive force [N] or torque
    # [N m] for a generic drive axis (``plants/motor_axis.py``), so Coulomb friction of 20 N is in range
    force_scale: float = 1.0
    linear: bool = False  # a linear axis: its "torques" are forces [N], its angles positions [m]


@dataclass(frozen=True)
class MeasuredPort:
    """A measured output: ``signal`` is the model's output in the recording (``iris_angle_deg``),
    ``kind`` and ``unit`` what it is, ``sensor`` what measures it on a rig (``encoder``, ``adc`` or
    ``none`` for a signal only a lab instrument records). ``wire`` is the sensor's input (the true
    quantity in SI units): sensor effects are inserted there and the simulated rig reads it.
    ADC sensors carry their calibration: counts = offset_counts + counts_per_unit * value."""

    signal: str
    kind: MeasuredKind
    unit: str
    sensor: Literal["encoder", "adc", "none"] = "none"
    wire: Wire | None = None
    counts_per_unit: float = 0.0
    offset_counts: float = 0.0


@dataclass(frozen=True)
class HeatPort:
    """A heat input: the temperature signal and the (part, port) where extra heat flow is summed."""

    temperature: str
    into: tuple[str, str]
    ambient_c: float


@dataclass(frozen=True)
class TemperatureWire:
    """The temperature a material law reads (an SMA wire's phase transformation), and its value
    at rest: a hysteresis inserted there starts from it."""

    wire: Wire
    initial_c: float


@dataclass(frozen=True)
class Ports:
    """Every port of one plant under one config."""

    actuators: tuple[ActuatorPort, ...] = ()
    axes: tuple[AxisPort, ...] = ()
    measured: tuple[MeasuredPort, ...] = ()
    heat: tuple[HeatPort, ...] = ()
    transformation_temperature: tuple[TemperatureWire, ...] = ()
    constants: Mapping[str, float] = field(default_factory=dict)  # inputs the config holds (SI units)
    # the signals several parts add onto (every joint's torque sum, heat flows): the only signals
    # the plant's diagram lets have more than one producer (``Diagram(..., sums=...)``)
    sums: tuple[str, ...] = ()
    # the plant input a patient's torque on the primary axis enters by, and its sign against the axis
    # (the Finger Extensor's ``patient_torque_nm``, opposing opening: -1); None: summed onto the axis torque
    interaction: tuple[str, float] | None = None

    def of_kind(self, kind: str) -> tuple[object, ...]:
        """The ports of one kind (``PORT_KINDS``), primary first."""
        if kind == "actuator":
            return self.actuators
        if kind == "axis":
            return self.axes
        if kind == "finger_axis":
            return tuple(a for a in self.axes if a.finger)
        if kind in ("encoder", "adc"):
            return tuple(m for m in self.measured if m.sensor == kind and m.wire is not None)
        if kind == "heat":
            return self.heat
        if kind == "transformation_temperature":
            return self.transformation_temperature
        raise KeyError(f"unknown port kind {kind!r}; kinds are {PORT_KINDS}")

    def kinds(self) -> set[str]:
        """The port kinds this plant offers."""
        return {k for k in PORT_KINDS if self.of_kind(k)}

    def measured_kind(self, signal: str) -> str | None:
        """What a measured signal is (``angle``, ``force``, ...), or None if not a measured port."""
        return next((m.kind for m in self.measured if m.signal == signal), None)
