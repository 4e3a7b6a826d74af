"""Host safety supervisor: mirrors the firmware's limits a margin inside them, adds what the
firmware cannot know (estimated actuator temperature), and watches the device and the link.

Checks each cycle: range of motion, contact force, estimated temperature, continuous heating
time, device fault bits, link loss (N cycles in a row without a sample), device reboot, and a
stuck sensor (driving hard, far from the reference, and the encoder does not move: a frozen
encoder would otherwise defeat the range-of-motion limits). Any trip
latches the safe state: every later command is PWM 0 / disabled, and the reason is logged.
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass

from rehab_hil.protocol import Fault
from rehab_hil.service.controllers import SAFE_COMMAND, Command
from rehab_hil.service.estimation import State
from rehab_hil.service.thermal import FirstOrderThermal

__all__ = ["SafetyEvent", "Supervisor", "SupervisorLimits"]

log = logging.getLogger("rehab_hil.supervisor")


@dataclass(frozen=True)
class SafetyEvent:
    """One trip: when (loop time), which check, and the values that tripped it."""

    t_s: float
    reason: str
    detail: str


@dataclass(frozen=True)
class SupervisorLimits:
    """The host's own trip levels (already tightened inside the firmware's)."""

    min_angle_deg: float
    max_angle_deg: float
    max_force_n: float
    max_heating_s: float
    max_temperature_c: float
    link_loss_periods: int
    max_duty: float
    stuck_sensor_s: float = 0.0  # 0 = off
    stuck_min_duty: float = 1.0
    stuck_min_error_deg: float = 10.0
    stuck_min_motion_deg: float = 1.0


class Supervisor:
    """Judges every cycle; ``filter`` turns a controller's command into what may be sent."""

    def __init__(self, limits: SupervisorLimits, dt_s: float, force_signals: tuple[str, ...] = (),
                 thermal: FirstOrderThermal | None = None) -> None:
        self.limits, self.dt_s, self.force_signals, self.thermal = limits, dt_s, force_signals, thermal
        self.events: list[SafetyEvent] = []
        self.heating_s = 0.0
        self.missing = 0
        self.max_temperature_c = thermal.temperature_c if thermal else math.nan
        self._sent_duty = 0.0
        self._sent_reference_deg = math.nan
        self._still_since: tuple[float, float] | None = None  # (t_s, angle_deg) when driving began

    @property
    def tripped(self) -> bool:
        return bool(self.events)

    @property
    def temperature_c(self) -> float:
        return self.thermal.temperature_c if self.thermal else math.nan

    def trip(self, t_s: float, reason: str, detail: str = "") -> None:
        """Latch the safe state (the first reason is the one that counts; later ones are logged too)."""
        if any(e.reason == reason for e in self.events):
            return
        self.events.append(SafetyEvent(t_s, reason, detail))
        log.error("safety trip at t=%.3f s: %s %s", t_s, reason, detail)

    def observe(self, t_s: float, state: State, faults: int) -> None:
        """Check one received sample's estimate and the device's fault bits."""
        self.missing = 0
        lim = self.limits
        a = state.angle_deg
        if not lim.min_angle_deg <= a <= lim.max_angle_deg:
            self.trip(t_s, "range_of_motion", f"angle {a:.2f} deg outside [{lim.min_angle_deg}, {lim.max_angle_deg}]")
        for name in self.force_signals:
            f = state.analog.get(name, 0.0)
            if f > lim.max_force_n:
                self.trip(t_s, "contact_force", f"{name} {f:.2f} N > {lim.max_force_n} N")
        if faults:
            self.trip(t_s, "device_fault", "+".join(Fault.names(faults)) or f"bits 0x{faults:04x}")
        self._check_stuck(t_s, a)

    def _check_stuck(self, t_s: float, angle_deg: float) -> None:
        """'Is it changing' (as opensourceleg's SafetyManager): only while the last command drove at
        ``stuck_min_duty`` or more and the angle is far from its reference, so holds never trip."""
        lim = self.limits
        error = abs(self._sent_reference_deg - angle_deg)  # nan (no reference) compares False
        driving = self._sent_duty >= lim.stuck_min_duty and error > lim.stuck_min_error_deg
        if lim.stuck_sensor_s <= 0.0 or not driving:
            self._still_since = None
            return
        if self._still_since is None or abs(angle_deg - self._still_since[1]) >= lim.stuck_min_motion_deg:
            self._still_since = (t_s, angle_deg)
        elif t_s - self._still_since[0] >= lim.stuck_sensor_s:
            self.trip(t_s, "stuck_sensor", f"duty {self._sent_duty:.2f}, {error:.1f} deg from the reference, "
                      f"angle within {lim.stuck_min_motion_deg} deg for {t_s - self._still_since[0]:.2f} s")

    def no_sample(self, t_s: float) -> None:
        """A cycle passed without a sample; ``link_loss_periods`` in a row is a lost link."""
        self.missing += 1
        if self.missing >= self.limits.link_loss_periods:
            self.trip(t_s, "link_loss", f"no sample for {self.missing} periods")

    def reboot(self, t_s: float, detail: str) -> None:
        self.trip(t_s, "device_reboot", detail)

    def filter(self, t_s: float, cmd: Command) -> Command:
        """Clamp duties to ``max_duty``; zero everything once tripped. Advances the thermal model
        and the heating-time count with the duty that will actually be sent."""
        if not self.tripped:
            d0 = min(max(cmd.duty[0], 0.0), self.limits.max_duty)
            d1 = min(max(cmd.duty[1], 0.0), self.limits.max_duty)
            if (d0, d1) != cmd.duty:
                cmd = Command((d0, d1), cmd.direction, cmd.enable, cmd.reference_deg)
        out = SAFE_COMMAND if self.tripped else cmd
        duty = max(out.duty) if out.enable else 0.0
        self._sent_duty, self._sent_reference_deg = duty, out.reference_deg
        self.heating_s = self.heating_s + self.dt_s if duty > 0.0 else 0.0
        if self.thermal is not None:
            temp = self.thermal.step(duty, self.dt_s)
            self.max_temperature_c = max(self.max_temperature_c, temp)
            if temp > self.limits.max_temperature_c and not self.tripped:
                self.trip(t_s, "temperature", f"estimated {temp:.1f} C > {self.limits.max_temperature_c} C")
        if self.heating_s >= self.limits.max_heating_s and not self.tripped:
            self.trip(t_s, "heating_time", f"PWM on for {self.heating_s:.3f} s >= {self.limits.max_heating_s} s")
        return SAFE_COMMAND if self.tripped else out
