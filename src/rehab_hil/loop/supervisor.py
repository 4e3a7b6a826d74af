"""Host safety supervisor: mirrors the firmware's limits a margin inside them, adds what the
firmware cannot know (estimated actuator temperature), and watches the device and the link.

Checks: range of motion, contact force (debounced), the e-stop input (status bit), estimated and
measured temperature (and their agreement), continuous heating time, device fault bits, link
loss, device reboot, and a stuck sensor (driving hard, far from the reference, and the encoder
does not move). A silence of a local simulated device whose process could not run (``starvation``:
waiting for a CPU, or stopped) is its stall, not a lost link: it is recorded in ``device_stalls``
and only the time it could run counts towards the link-loss budget. Every timer runs on device
time (``t_s`` = sample index x period), never on
loop cycles: over a USB bridge samples arrive 2-4 at a time and the loop runs once per burst.
Only link loss is on the host clock (no samples means no device time). Any trip latches the
safe state: every later command is PWM 0 / disabled, and the reason is logged.
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass
from typing import Any, Protocol

from rehab_hil.loop.controllers import SAFE_COMMAND, Command
from rehab_hil.loop.estimation import State
from rehab_hil.loop.thermal import SafetyThermal, ThermalTightening
from rehab_hil.protocol import Fault, Status

__all__ = ["DeviceStall", "SafetyEvent", "Supervisor", "SupervisorLimits"]

log = logging.getLogger("rehab_hil.supervisor")


@dataclass(frozen=True)
class SafetyEvent:
    """One trip: when (loop time), which check, and the values that tripped it."""

    t_s: float
    reason: str
    detail: str
    cause: str = ""  # whose stall it was and how long, with a hint (loop/trip_cause.py); "" = a limit


@dataclass
class DeviceStall:
    """A silence of the link while the local simulated device's process could not run (not a trip):
    from device time ``t_s``, ``silent_s`` without a sample, ``starved_s`` of it not scheduled."""

    t_s: float
    silent_s: float
    starved_s: float


class StarvationProbe(Protocol):
    """How long the device's process could not run since ``start()`` (devices/starvation.py)."""

    def start(self) -> None: ...

    def poll(self) -> float: ...

    def alive(self) -> bool: ...


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
    force_debounce_s: float = 0.0  # force above the limit this long (device time) trips; 0 = first sample
    max_disagreement_c: float = 25.0  # measured vs estimated temperature
    disagreement_s: float = 1.0


class Supervisor:
    """Judges every cycle; ``filter`` turns a controller's command into what may be sent."""

    def __init__(self, limits: SupervisorLimits, dt_s: float, force_signals: tuple[str, ...] = (),
                 thermal: Any = None, *, estop_input: bool = False,
                 temperature_signal: str | None = None) -> None:
        """``thermal``: the actuator temperature estimate (``plants.thermal.safety_thermal``: the plant's own
        model, or ``control.thermal.ModalThermal``), advanced by device time on the duty sent."""
        self.limits, self.dt_s, self.force_signals, self.thermal = limits, dt_s, force_signals, thermal
        self._thermal = SafetyThermal(thermal) if thermal is not None else None
        self.estop_input, self.temperature_signal = estop_input, temperature_signal
        self.events: list[SafetyEvent] = []
        self.tripped = False  # latched by the first event (a plain attribute: read several times a cycle)
        self.heating_s = 0.0
        self.missing = 0
        self.max_temperature_c = thermal.temperature_c if thermal else math.nan
        self.measured_temperature_c = math.nan
        self._heating_since: float | None = None  # device time the drive went on
        self._force_since: dict[str, float] = {}
        self._disagree_since: float | None = None
        self._last_arrival: float | None = None  # host clock of the last sample (link loss only)
        self._sent_duty = 0.0
        self._sent_reference_deg = math.nan
        self._still_since: tuple[float, float] | None = None  # (t_s, angle_deg) when driving began
        self.starvation: StarvationProbe | None = None  # a local simulated device's process (set by the loop)
        self.device_stalls: list[DeviceStall] = []
        self._stall_of: float | None = None  # the arrival the last device stall followed


    @property
    def temperature_c(self) -> float:
        return self.thermal.temperature_c if self.thermal else math.nan

    def thermal_state(self, t_s: float) -> Any:
        """The temperature estimate's state at device time ``t_s`` (the controller's observer follows it)."""
        return self._thermal.state_at(t_s) if self._thermal is not None else None

    def tighten_thermal(self, t_s: float, change: ThermalTightening) -> bool:
        """Stricter values for the temperature estimate (``loop/thermal.py``), between two cycles."""
        return self._thermal is not None and self._thermal.tighten(t_s, change)

    @property
    def thermal_changes(self) -> list[dict[str, Any]]:
        """Each tightening of the temperature estimate taken (device time, values, temperature)."""
        return self._thermal.changes if self._thermal is not None else []

    def trip(self, t_s: float, reason: str, detail: str = "") -> None:
        """Latch the safe state (the first reason is the one that counts; later ones are logged too)."""
        if any(e.reason == reason for e in self.events):
            return
        self.events.append(SafetyEvent(t_s, reason, detail))
        self.tripped = True
        log.error("safety trip at t=%.3f s: %s %s", t_s, reason, detail)

    def observe(self, t_s: float, state: State, faults: int, status: int = 0,
                arrival_s: float | None = None) -> None:
        """Check one received sample (device time ``t_s``): its estimate, the e-stop status bit and
        the device's fault bits. ``arrival_s`` (host clock) restarts the link-loss timer."""
        self.missing = 0
        if arrival_s is not None:
            self._last_arrival = arrival_s
        lim = self.limits
        a = state.angle_deg
        if not lim.min_angle_deg <= a <= lim.max_angle_deg:
            self.trip(t_s, "range_of_motion", f"angle {a:.2f} deg outside [{lim.min_angle_deg}, {lim.max_angle_deg}]")
        for name in self.force_signals:
            f = state.analog.get(name, 0.0)
            if f <= lim.max_force_n:
                self._force_since.pop(name, None)
                continue
            since = self._force_since.setdefault(name, t_s)
            if t_s - since + self.dt_s >= lim.force_debounce_s - 1e-9:  # N samples of device time
                self.trip(t_s, "contact_force", f"{name} {f:.2f} N > {lim.max_force_n} N for "
                          f"{(t_s - since) * 1e3 + self.dt_s * 1e3:.0f} ms")
        if self.estop_input and status & Status.ESTOP_INPUT_ACTIVE:
            self.trip(t_s, "estop_input", "e-stop input active (button pressed or its loop broken)")
        if self.temperature_signal is not None and self.temperature_signal in state.analog:
            self._check_measured_temperature(t_s, state.analog[self.temperature_signal])
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

    def _check_measured_temperature(self, t_s: float, measured_c: float) -> None:
        """A thermistor (A1) where one is wired: its reading trips the limit like the estimate, and a
        lasting disagreement with the estimate is a fault (a broken sensor or a wrong model)."""
        lim = self.limits
        self.measured_temperature_c = measured_c
        self.max_temperature_c = max(self.max_temperature_c, measured_c) if math.isfinite(
            self.max_temperature_c) else measured_c
        if measured_c > lim.max_temperature_c:
            self.trip(t_s, "temperature", f"measured {measured_c:.1f} C > {lim.max_temperature_c} C")
        if self.thermal is None:
            return
        diff = measured_c - self.thermal.temperature_c
        if abs(diff) <= lim.max_disagreement_c:
            self._disagree_since = None
            return
        if self._disagree_since is None:
            self._disagree_since = t_s
        elif t_s - self._disagree_since >= lim.disagreement_s:
            self.trip(t_s, "temperature_disagreement",
                      f"measured {measured_c:.1f} C vs estimated {self.thermal.temperature_c:.1f} C for "
                      f"{t_s - self._disagree_since:.2f} s (sensor broken or thermal model wrong)")

    def no_sample(self, t_s: float, now_s: float | None = None) -> None:
        """A wait for a sample ended empty. With ``now_s`` (host clock) the link counts as lost once
        no sample has arrived for ``link_loss_periods`` x the period and at least two waits in a row
        came back empty (one unanswered request to a lockstep device is a lost frame, not a lost
        link); without it, after ``link_loss_periods`` empty waits in a row."""
        self.missing += 1
        budget_s = self.limits.link_loss_periods * self.dt_s
        if now_s is not None and self._last_arrival is not None:
            probe = self.starvation
            if probe is not None and self.missing == 1:
                probe.start()  # a silence begins: how much of it the device can run from here
            silent = now_s - self._last_arrival
            if silent >= budget_s and self.missing >= 2:
                self._judge_silence(t_s, silent, budget_s)
        elif self.missing >= self.limits.link_loss_periods:
            self.trip(t_s, "link_loss", f"no sample for {self.missing} periods")

    def silent_beyond_budget(self, now_s: float) -> bool:
        """No sample for the whole link-loss budget (host clock): worth one more look at the port
        before judging (a host that stalled in its wait finds the samples that came meanwhile)."""
        last = self._last_arrival
        return last is not None and now_s - last >= self.limits.link_loss_periods * self.dt_s

    def _judge_silence(self, t_s: float, silent: float, budget_s: float) -> None:
        """A silence over the budget: a lost link, unless the device's process could not run for
        enough of it (then a device stall, recorded; the budget counts the time it could run)."""
        probe = self.starvation
        starved = probe.poll() if probe is not None else 0.0
        text = f"no sample for {silent * 1e3:.1f} ms (budget {budget_s * 1e3:.0f} ms)"
        if silent - starved >= budget_s:
            if probe is not None:
                text += (f"; the device process could not run for {starved * 1e3:.1f} ms of it" if probe.alive()
                         else "; the device process has exited")
            self.trip(t_s, "link_loss", text)
            return
        if self._stall_of != self._last_arrival or not self.device_stalls:
            self._stall_of = self._last_arrival
            self.device_stalls.append(DeviceStall(t_s, silent, starved))
        else:
            st = self.device_stalls[-1]
            st.silent_s, st.starved_s = silent, starved

    def reboot(self, t_s: float, detail: str) -> None:
        self.trip(t_s, "device_reboot", detail)

    def forget_events(self, n: int) -> None:
        """Keep only the first ``n`` events (the loop's shutdown: samples read there judge no more trips)."""
        del self.events[n:]
        self.tripped = bool(self.events)

    def admit(self, t_s: float, cmd: Command) -> Command:
        """The command the rig may get: duties clamped to ``max_duty``, everything zero once tripped.
        Not a pure filter: it advances the thermal model and the heating time by the device time
        since the last call (``t_s`` is the newest sample's device time) with the duty sent then,
        counts the duty sent now, and may trip on either (heating time, temperature)."""
        if not self.tripped:
            d0 = min(max(cmd.duty[0], 0.0), self.limits.max_duty)
            d1 = min(max(cmd.duty[1], 0.0), self.limits.max_duty)
            if (d0, d1) != cmd.duty:
                cmd = Command((d0, d1), cmd.direction, cmd.enable, cmd.reference_deg)
        out = SAFE_COMMAND if self.tripped else cmd
        duty = max(out.duty) if out.enable else 0.0
        self._sent_duty, self._sent_reference_deg = duty, out.reference_deg
        if duty > 0.0:  # on-time to the end of this period, as the firmware counts its ticks
            if self._heating_since is None:
                self._heating_since = t_s
            self.heating_s = t_s - self._heating_since + self.dt_s
        else:
            self._heating_since, self.heating_s = None, 0.0
        if self._thermal is not None:  # the periods a burst skipped with the duty held, then this one's
            temp = self._thermal.apply(t_s, duty, self.dt_s)
            self.max_temperature_c = max(self.max_temperature_c, temp)
            if temp > self.limits.max_temperature_c and not self.tripped:
                self.trip(t_s, "temperature", f"estimated {temp:.1f} C > {self.limits.max_temperature_c} C")
        if self.heating_s >= self.limits.max_heating_s and not self.tripped:
            self.trip(t_s, "heating_time", f"PWM on for {self.heating_s:.3f} s >= {self.limits.max_heating_s} s")
        return SAFE_COMMAND if self.tripped else out
