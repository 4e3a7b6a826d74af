"""How a plant sits behind the rig's I/O: the rig binding and its typed interfaces, in the spirit of
ros2_control's state and command interfaces.

Value types, shared by the plants (whose ports derive the binding, ``Plant.device``), the
simulated devices, the loop service and the twin (which convert with them), and the hardware
layer (whose contract checks them against the device, ``rehab_hil.hardware.contract``). This
module imports only the standard library (the model types it names are for type checking only),
so a plant can describe its interfaces without pulling in the serial link or the hardware
implementations, and the hardware layer can check them without loading the model engine.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING, Literal

if TYPE_CHECKING:  # types only: the binding carries parts and a schedule, this module loads no model engine
    from rehab_hil.models.schedule import Schedule
    from rehab_hil.models.system import Part

__all__ = ["AdcChannel", "Claims", "CommandInterface", "DeviceBinding", "Source", "StateInterface",
           "StateKind"]

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
    ``channel``: value = scale * duty (0..1), negated by the channel's direction pin when ``signed``
    (an H-bridge); e.g. motor_voltage_v = 24 * duty. The one place effort <-> duty is written: the
    loop's actuator, the recorder, the twin and the simulated rig convert with it."""

    name: str
    unit: str  # of the plant input (the actuator port's unit)
    channel: int
    scale: float  # the value at full duty
    signed: bool = False

    def direction_sign(self, direction_bits: int) -> float:
        """-1.0 when this input is signed and its channel's bit in ``direction_bits`` is set, else 1.0."""
        return -1.0 if self.signed and direction_bits >> self.channel & 1 else 1.0

    def effort(self, duty: float, direction_bits: int) -> float:
        """The value on the plant input while ``duty`` (0..1) is applied with ``direction_bits``."""
        return self.direction_sign(direction_bits) * self.scale * duty

    def duty(self, effort: float) -> tuple[float, bool]:
        """(duty 0..1, reversed) that applies ``effort``: |effort| / scale, at most 1, reversed when
        the effort is negative on a signed input; an unsigned input applies no negative effort (0)."""
        u = effort if self.signed else max(effort, 0.0)
        return min(abs(u) / self.scale, 1.0), u < 0.0


@dataclass(frozen=True)
class Claims:
    """The interfaces a controller uses, by name: command interfaces it writes, state interfaces
    it reads. ``rehab_hil.hardware.contract.on_configure`` refuses a claim the binding does not
    provide."""

    command: tuple[str, ...] = ()
    state: tuple[str, ...] = ()


@dataclass(frozen=True)
class AdcChannel:
    """An analog input the firmware samples: counts = offset + per_unit * signal, clipped to 0..1023.
    The calibration behind a state interface of source ``adc<i>`` (``DeviceBinding.state_interfaces``).

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
    duty_inputs: dict[str, CommandInterface]  # by plant input name: the PWM-driven inputs
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

    @property
    def encoder_count_deg(self) -> float:
        """One encoder count [deg] (0: no encoder)."""
        return 360.0 / self.encoder_counts_per_rev if self.encoder_signal and self.encoder_counts_per_rev else 0.0

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
        return tuple(self.duty_inputs.values())

    def state(self, kind: str) -> StateInterface | None:
        """The first state interface of a kind (``angle``, ``force``, ``torque``, ``temperature``)."""
        return next((s for s in self.state_interfaces if s.kind == kind), None)

    @property
    def reference_column(self) -> str:
        """The recorded reference of the encoder angle, beside ``angle_output`` [deg]."""
        return self.angle_output.removesuffix("_deg") + "_reference_deg"
