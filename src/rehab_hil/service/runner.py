"""The real-time loop service: read a sample, estimate, control, supervise, command; record and
publish off-thread. One run = configure the device, loop for a duration (or until a trip or a stop
request), then leave the device in the safe state (PWM 0) and report.

Pacing (docs/loop.md): ``device`` reacts to the device's sample stream (each SAMPLE starts a cycle;
in lockstep mode each COMMAND produces the next SAMPLE); ``host`` wakes on absolute deadlines of a
monotonic clock and consumes what arrived. Samples that arrive while a cycle is busy are still
estimated, supervised and recorded, but only the newest is controlled: the skipped ones count as
missed cycles (never caught up).
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from rehab_hil import metrics
from rehab_hil.hardware.interface import HardwareError, HardwareInterface, LifecycleState
from rehab_hil.protocol import Configure, Sample, Status
from rehab_hil.service.controllers import SAFE_COMMAND, Command, Controller
from rehab_hil.service.estimation import Estimator, State
from rehab_hil.service.loop import DeadlineTimer, RealtimeReport, TimingStats, realtime_setup, realtime_teardown
from rehab_hil.service.recorder import Record, Recorder
from rehab_hil.service.supervisor import SafetyEvent, Supervisor
from rehab_hil.service.telemetry import NullSink, TelemetrySink
from rehab_hil.session_metrics import SessionMeter

__all__ = ["LoopService", "Progress", "RunResult"]

CONFIRM_CYCLES = 20  # cycles spent after a trip confirming the device reports PWM 0


@dataclass
class Progress:
    """Live figures the display thread reads (plain floats; written by the loop thread)."""

    t_s: float = 0.0
    duration_s: float = 0.0
    angle_deg: float = math.nan
    reference_deg: float = math.nan
    duty: float = 0.0
    temperature_c: float = math.nan
    samples: int = 0
    missed: int = 0
    tripped: str = ""
    last_cycle: dict[str, float] = field(default_factory=dict)  # the last finished open-close cycle's figures


@dataclass
class RunResult:
    """Everything the summary prints."""

    pacing: str
    realtime: RealtimeReport | None
    duration_s: float
    cycles: int
    samples: int
    sample_gaps: int  # samples missing from the device's sample_index sequence
    reboots: int
    timing: dict[str, float]
    reaction: dict[str, float]
    tracking: dict[str, float]
    link: dict[str, Any]
    events: list[SafetyEvent]
    recorder_dropped: int
    telemetry_dropped: int
    final_sample: Sample | None
    stop_reason: str
    files: list[str] = field(default_factory=list)
    session: dict[str, float] = field(default_factory=dict)  # per-cycle figures summed up (session_metrics)
    session_cycles: list[dict[str, float]] = field(default_factory=list)

    @property
    def pwm_off_at_end(self) -> bool:
        s = self.final_sample
        return s is not None and s.duty0 == 0 and s.duty1 == 0 and not (s.status & Status.PWM_ENABLED)


class LoopService:
    """Runs one session on a connected ``HardwareInterface``; see the module docstring."""

    def __init__(self, hw: HardwareInterface, configure: Configure, controller: Controller, estimator: Estimator,
                 supervisor: Supervisor, period_s: float, recorder: Recorder | None = None,
                 telemetry: TelemetrySink | None = None, meter: SessionMeter | None = None) -> None:
        self.hw, self.configure_msg, self.controller = hw, configure, controller
        self.estimator, self.supervisor, self.period_s = estimator, supervisor, period_s
        self.recorder, self.telemetry = recorder, telemetry or NullSink()
        self.meter = meter
        actuator = getattr(controller, "actuator", None)
        self._effort_of = actuator.effort if actuator is not None else (lambda cmd: math.nan)
        self.progress = Progress()
        self._stop_reason = ""
        self._seq = -1

    def request_stop(self, reason: str) -> None:
        """From a signal handler: the loop trips into the safe state at its next cycle and exits."""
        self._stop_reason = reason

    # ------------------------------------------------------------------------------------------
    def run(self, duration_s: float, pacing: str = "device", realtime: bool = True,
            sample_timeout_s: float | None = None,
            on_trip: Callable[[SafetyEvent], None] | None = None) -> RunResult:
        """Loop for ``duration_s`` of samples. ``sample_timeout_s`` (device pacing) is how long a
        cycle waits for its sample before it counts as missing (default: one period; lockstep
        devices on a busy machine need more)."""
        if pacing not in ("device", "host"):
            raise ValueError(f"pacing must be 'device' or 'host', got {pacing!r}")
        n_max = max(1, round(duration_s / self.period_s))
        self.progress.duration_s = duration_s
        refs = np.full(n_max, np.nan)
        angles = np.full(n_max, np.nan)
        reaction = TimingStats(n_max)
        timer = DeadlineTimer(self.period_s, n_max)
        self._last_index: int | None = None
        self._cont_index = -1
        self._gaps = 0
        self._reboots = 0
        self._reboots_seen = self.hw.stats.reboots
        self._samples = 0
        self._final: Sample | None = None
        self._state: State | None = None
        cycles = 0
        rt: RealtimeReport | None = None
        stop_reason = "duration reached"
        for t in (0.0, self.period_s):  # warm up: numba kernels (sample, integrate) load before the watchdog runs
            self.controller(t, State(t, 0.0, 0.0, {}))
        self.controller.reset()
        if realtime:  # before CONFIGURE: a full GC pass can take longer than the firmware watchdog
            rt = realtime_setup()
        try:
            self.hw.configure(self.configure_msg)
            self.hw.discard_pending()  # samples queued before the ACK belong to the old stream, not this session
            self._send(SAFE_COMMAND)  # arms the watchdog; in lockstep mode it produces the first sample
            timer.start()
            k = 0
            while k < n_max:
                if pacing == "host":
                    k = timer.wait()
                    if k >= n_max:
                        break
                    got = self._drain(first_timeout=1e-5)
                else:
                    got = self._drain(first_timeout=sample_timeout_s or self.period_s)
                t_s = (self._cont_index if pacing == "device" and self._cont_index >= 0 else k) * self.period_s
                if self._stop_reason:
                    self.supervisor.trip(t_s, "stop_request", self._stop_reason)
                if self.hw.stats.reboots != self._reboots_seen:  # an unsolicited HELLO arrived
                    self._reboots += 1
                    self._reboots_seen = self.hw.stats.reboots
                    self.supervisor.reboot(t_s, "unsolicited HELLO (device restarted)")
                if got == 0:
                    self.supervisor.no_sample(t_s, time.perf_counter())
                else:
                    timer.stats.missed += got - 1 if pacing == "device" else 0
                if self.supervisor.tripped:
                    stop_reason = f"safety trip: {self.supervisor.events[0].reason}"
                    break
                if got == 0:  # nothing new: repeat the last command (a lockstep device needs a COMMAND
                    self._send(self._last_cmd())  # to produce a SAMPLE; the link-loss count guards this)
                    k += pacing == "device"
                    continue
                state = self._state
                assert state is not None
                cmd = self.supervisor.filter(t_s, self.controller(t_s, state))
                self._send(cmd)
                if self.supervisor.tripped:  # the filter itself tripped (heating, temperature)
                    stop_reason = f"safety trip: {self.supervisor.events[0].reason}"
                    break
                reaction.add(time.perf_counter() - self.hw.last_sample_time)
                self._offer(t_s, cmd)
                if self.meter is not None:
                    self._meter(t_s, state, cmd)
                if cycles < n_max:
                    refs[cycles], angles[cycles] = cmd.reference_deg, state.angle_deg
                cycles += 1
                if pacing == "device":
                    k = self._cont_index + 1
                if cycles % 50 == 0:
                    self._update_progress(t_s, state, cmd)
        finally:
            if realtime:
                realtime_teardown()
            self._shutdown(on_trip)
        timing = timer.stats.summary() if pacing == "host" else reaction.summary()
        if pacing == "device":
            timing["missed_cycles"] = float(timer.stats.missed + self._gaps)
            total = cycles + timing["missed_cycles"]
            timing["missed_pct"] = 100.0 * timing["missed_cycles"] / total if total else 0.0
        ok = np.isfinite(refs[:cycles]) & np.isfinite(angles[:cycles])
        tracking = metrics.tracking_metrics(refs[:cycles][ok], angles[:cycles][ok]) if ok.any() else {}
        return RunResult(
            pacing=pacing, realtime=rt, duration_s=duration_s, cycles=cycles, samples=self._samples,
            sample_gaps=self._gaps, reboots=self._reboots, timing=timing, reaction=reaction.summary(),
            tracking=tracking, link=self.hw.stats.as_dict(), events=list(self.supervisor.events),
            recorder_dropped=self.recorder.dropped if self.recorder else 0,
            telemetry_dropped=int(getattr(self.telemetry, "dropped", 0)), final_sample=self._final,
            stop_reason=f"safety trip: {self.supervisor.events[0].reason}" if self.supervisor.events else stop_reason,
            files=[str(self.recorder.csv_path), str(self.recorder.mcap_path)] if self.recorder else [],
            session=self.meter.summary() if self.meter else {},
            session_cycles=[c.as_dict() for c in self.meter.cycles] if self.meter else [],
        )

    # ------------------------------------------------------------------------------------------
    def _send(self, cmd: Command) -> None:
        try:
            self._seq = self.hw.write_command(cmd.duty[0], cmd.duty[1], cmd.direction, cmd.enable)
        except HardwareError as e:
            self.supervisor.trip(self._cont_index * self.period_s, "link_loss", f"write failed: {e}")

    def _drain(self, first_timeout: float) -> int:
        """Take every sample that has arrived (waiting up to ``first_timeout`` for the first one);
        each is estimated, supervised and recorded. Returns how many were taken."""
        n = 0
        timeout = first_timeout
        while True:
            try:
                s = self.hw.read_sample(timeout=timeout)
            except HardwareError as e:
                self.supervisor.trip(self._cont_index * self.period_s, "link_loss", str(e))
                return n
            if s is None:
                return n
            self._take(s)
            n += 1
            if self.hw.pending_samples() == 0:
                return n
            timeout = 0.0

    def _take(self, s: Sample) -> None:
        self._samples += 1
        self._final = s
        rebooted = self.hw.stats.reboots != self._reboots_seen
        if self._last_index is not None:
            step = (s.sample_index - self._last_index) & 0xFFFFFFFF
            if step >= 0x80000000 or rebooted:  # the index went back: the device restarted
                rebooted = True
            elif step > 1:
                self._gaps += step - 1
                self._cont_index += step - 1
        if rebooted:
            self._reboots += 1
            self._reboots_seen = self.hw.stats.reboots
            self.estimator.reset()
            self.supervisor.reboot(self._cont_index * self.period_s,
                                   f"sample_index {self._last_index} -> {s.sample_index}")
        self._last_index = s.sample_index
        self._cont_index += 1
        t_s = self._cont_index * self.period_s
        self._state = self.estimator.update(s.encoder_count, s.device_time_us, (s.adc0, s.adc1))
        self.supervisor.observe(t_s, self._state, s.faults, s.status, self.hw.last_sample_time)
        rec = Record(time.perf_counter(), t_s, s, self._state, SAFE_COMMAND if self.supervisor.tripped
                     else self._last_cmd(), self._seq, self.supervisor.temperature_c)
        if self.recorder is not None:
            self.recorder.offer(rec)
        self.telemetry.offer(rec)  # the same records as the recorder: a zenoh recording equals a local one

    def _last_cmd(self) -> Command:
        return getattr(self, "_cmd", SAFE_COMMAND)

    def _offer(self, t_s: float, cmd: Command) -> None:
        self._cmd = cmd
        rec = Record(time.perf_counter(), t_s, None, None, cmd, self._seq, self.supervisor.temperature_c)
        if self.recorder is not None:
            self.recorder.offer(rec)
        self.telemetry.offer(rec)

    def _meter(self, t_s: float, state: State, cmd: Command) -> None:
        """After the command is out: the session meter's sample, and a finished cycle's figures to
        the recording (MCAP ``/rig/cycle``) and the live stats (telemetry, Foxglove)."""
        assert self.meter is not None
        self.meter.add(t_s, cmd.reference_deg, state.angle_deg, self._effort_of(cmd), state.velocity_rad_s,
                       self.supervisor.temperature_c)
        cycle = self.meter.poll()
        if cycle is not None:
            self.progress.last_cycle = cycle.as_dict()
            if self.recorder is not None:
                self.recorder.cycle(cycle.as_dict())

    def _update_progress(self, t_s: float, state: State, cmd: Command) -> None:
        p = self.progress
        p.t_s, p.angle_deg, p.reference_deg = t_s, state.angle_deg, cmd.reference_deg
        p.duty, p.temperature_c, p.samples = max(cmd.duty), self.supervisor.temperature_c, self._samples
        p.missed = self._gaps

    def _shutdown(self, on_trip: Callable[[SafetyEvent], None] | None) -> None:
        """PWM 0 now; after a trip also ESTOP, then watch a few samples confirm PWM off. Nothing to
        do on a device that was never configured (its CONFIGURE failed): it is not driving."""
        self._cmd = SAFE_COMMAND
        if self.hw.state is not LifecycleState.ACTIVE:
            return
        self._send(SAFE_COMMAND)
        sup = self.supervisor
        if sup.tripped:
            self.progress.tripped = sup.events[0].reason
            for ev in sup.events:
                if self.recorder is not None:
                    self.recorder.event(ev.t_s, ev.reason, ev.detail)
                if on_trip is not None:
                    on_trip(ev)
            if sup.events[0].reason not in ("link_loss",):
                try:
                    self.hw.estop(timeout=0.5)
                except HardwareError as e:
                    sup.trip(self._cont_index * self.period_s, "estop_unanswered", str(e))
        for _ in range(CONFIRM_CYCLES):  # lockstep devices answer each COMMAND with a SAMPLE
            if sup.events and sup.events[0].reason == "link_loss":
                break
            self._send(SAFE_COMMAND)
            try:
                s = self.hw.read_sample(timeout=2 * self.period_s)
            except HardwareError:
                break
            if s is not None:
                self._take_quiet(s)
            if self._final is not None and self._final.duty0 == 0 and self._final.duty1 == 0 \
                    and not self._final.status & Status.PWM_ENABLED:
                break

    def _take_quiet(self, s: Sample) -> None:
        """A sample during shutdown: recorded and counted, no more trips judged."""
        n_events = len(self.supervisor.events)
        self._take(s)
        del self.supervisor.events[n_events:]
