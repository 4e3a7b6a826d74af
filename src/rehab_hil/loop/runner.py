"""The real-time loop service: read a sample, estimate, supervise, control, write the command; then,
with the command out, hand the cycle's records on (``outlet``): to the figures and the sinks in this
process (lockstep, ``loop.dispatch``), or into the shared-memory ring that the session's process reads
(a loop process of its own, ``loop.process``). Sessions are built around it by ``service.session``.
One run = configure the device, loop for a duration (or until a trip or a stop request), then
leave the device in the safe state (PWM 0) and report.

Pacing (docs/loop.md): ``device`` reacts to the device's sample stream (each SAMPLE starts a cycle;
in lockstep mode each COMMAND produces the next SAMPLE); ``host`` wakes on absolute deadlines of a
monotonic clock and consumes what arrived. Samples that arrive while a cycle is busy are still
estimated, supervised and recorded, but only the newest is controlled: the older ones are
coalesced (never caught up) and count as missed cycles.

Nothing but the loop's own work happens before the write. What comes back to the loop (a stop
request, a learned table, stricter values for the temperature estimate) is taken at a cycle's start
(``mail``, a loop process's inbox).
"""

from __future__ import annotations

import dataclasses
import logging
import math
import time
from dataclasses import dataclass
from typing import Any, Protocol

from rehab_hil.hardware.interface import Arrival, HardwareError, HardwareInterface
from rehab_hil.loop.controllers import SAFE_COMMAND, Command, LoopController
from rehab_hil.loop.estimation import Estimator, State
from rehab_hil.loop.pacing import PACINGS, DevicePacing, HostPacing, RunState
from rehab_hil.loop.records import CommandRecord, EventRecord, SampleRecord
from rehab_hil.loop.shutdown import shut_down, stall_facts
from rehab_hil.loop.supervisor import SafetyEvent, Supervisor
from rehab_hil.loop.thermal import ThermalTightening
from rehab_hil.loop.timing import HELPER_NICE, RealtimeReport, realtime_setup, realtime_teardown, run_queue_wait_s
from rehab_hil.loop.trip_cause import StallFacts
from rehab_hil.protocol import Configure, Sample

__all__ = ["PACINGS", "LoopReport", "LoopService", "Outlet", "RunState"]

log = logging.getLogger(__name__)
# tuple.__new__ builds a record NamedTuple without its generated Python-level __new__ (as its _make
# does): half the cost, once per sample and per command on the loop thread
_new_record = tuple.__new__

MAX_TAKEN = 50  # samples taken in one cycle at the most (50 ms of samples at 1 kHz), then a command goes out
STALL_MARK_EVERY = 50  # cycles between marks of the loop thread's run-queue wait (a host stall's baseline)
CONFIGURE_TIMEOUT_S = 1.0  # a board answers CONFIGURE within milliseconds; 1 s is a dead or wrong port
# a simulated device spawned here is a process that may wait seconds for a CPU on a busy machine (two
# busy loops, load 15: "no ACK for Configure within 1.00 s" at session open); nothing heats before it
LOCAL_DEVICE_CONFIGURE_TIMEOUT_S = 10.0


class Outlet(Protocol):
    """Where the loop's records go after each write: ``loop.dispatch.Dispatch`` (figures and sinks in this
    process) or ``loop.ring.RingOutlet`` (the shared-memory ring of a loop process)."""

    def cycle(self, samples: list[SampleRecord], command: CommandRecord | None) -> None: ...

    def events(self, events: list[EventRecord]) -> None: ...


class Mail(Protocol):
    """What reaches a loop process from the session's process (``loop.process``): looked at once a cycle."""

    def check(self, loop: LoopService) -> None: ...


@dataclass
class LoopReport:
    """What the loop itself knows at its end (it crosses back from a loop process as it is); the session
    adds the figures of the records, the sinks' reports and its features' results (``RunResult``)."""

    pacing: str
    realtime: RealtimeReport | None
    duration_s: float  # asked for
    cycles: int
    samples: int
    sample_gaps: int  # samples missing from the device's sample_index sequence
    reboots: int
    timing: dict[str, float]
    reaction: dict[str, float]
    link: dict[str, Any]
    events: list[SafetyEvent]
    final_sample: Sample | None
    stop_reason: str
    ran_s: float = math.nan  # device time the session ran until it stopped (a trip, a stop request, the duration)
    stall_facts: StallFacts | None = None  # the causes of a stall trip are explained from these (trip_cause.py)
    pwm_unconfirmed: str = ""  # why no sample after the trip shows the PWM state ("" = confirmed or not needed)
    ring_overflow: int = 0  # a loop process's records written over unread ones (loop.ring)
    # each tightening of the supervisor's temperature estimate the loop took (loop/thermal.py): when, the values
    thermal_changes: list[dict[str, Any]] = dataclasses.field(default_factory=list)


class LoopService:
    """Runs one session on a connected ``HardwareInterface``; see the module docstring. ``outlet`` takes
    the records after each write; ``mail`` (a loop process's inbox) is looked at once a cycle."""

    def __init__(self, hw: HardwareInterface, configure: Configure, controller: LoopController, estimator: Estimator,
                 supervisor: Supervisor, period_s: float, outlet: Outlet, mail: Mail | None = None) -> None:
        self.hw, self.configure_msg, self.controller = hw, configure, controller
        self.estimator, self.supervisor, self.period_s = estimator, supervisor, period_s
        self.outlet, self.mail = outlet, mail
        self._advance = getattr(controller, "advance", None)  # the controller's work that can wait for the write
        self._last_step = getattr(controller, "last_step", None)  # what it computed, for the learning on the rig
        follow = getattr(controller, "follow_thermal", None)  # its observer on the supervisor's temperature estimate
        if follow is not None:
            follow(supervisor)
        self._stop_reason = ""
        self._stop_kind = "stop_request"
        self._host_clock = True  # link loss judged on the host's clock (run(lockstep=True): empty waits)
        self.run_state = RunState(period_s, 1, 0)

    def request_stop(self, reason: str, kind: str = "stop_request") -> None:
        """From a signal handler (or the twin, ``kind`` "model_mismatch"): the loop trips into the
        safe state at its next cycle and exits."""
        self._stop_kind = kind
        self._stop_reason = reason

    def tighten_thermal(self, change: ThermalTightening) -> None:
        """Stricter values for the supervisor's temperature estimate (``loop/thermal.py``), taken now, between
        two cycles, at the newest sample's device time (the loop's own thread only)."""
        self.supervisor.tighten_thermal(self.run_state.t_s, change)

    # ------------------------------------------------------------------------------------------
    def run(self, duration_s: float, pacing: str = "device", realtime: bool = True,
            sample_timeout_s: float | None = None, lockstep: bool = False) -> LoopReport:
        """Loop for ``duration_s`` of samples. ``sample_timeout_s`` (device pacing) is how long a
        cycle waits for its sample before it counts as missing (default: one period; lockstep
        devices on a busy machine need more). ``lockstep``: the device runs in virtual time, so
        the link is lost after ``link_loss_periods`` empty waits in a row, not after that much
        silence on the host's clock (a loaded machine pauses a lockstep device; nothing is lost)."""
        if pacing not in PACINGS:
            raise ValueError(f"pacing must be 'device' or 'host', got {pacing!r}")
        n_max = max(1, round(duration_s / self.period_s))
        s = self.run_state = RunState(self.period_s, n_max, self.hw.stats.reboots)
        pace = (DevicePacing(s, sample_timeout_s or self.period_s) if pacing == "device" else HostPacing(s))
        for t in (0.0, self.period_s):  # warm up: numba kernels (sample, integrate) load before the watchdog runs
            self.controller(t, State(t, 0.0, 0.0, {}))
        self.controller.reset()
        self._host_clock = not lockstep
        proc = getattr(self.hw, "device_process", None)  # a local simulated device: its stalls are not a lost link
        self.supervisor.starvation = proc.starvation() if proc is not None and not lockstep else None
        # before CONFIGURE: a full GC pass outlasts the watchdog; the other threads share the loop's GIL
        rt = realtime_setup(helper_nice=HELPER_NICE) if realtime else None
        try:
            self.hw.configure(self.configure_msg, timeout=_configure_timeout_s(lockstep, sample_timeout_s, proc))
            self.hw.discard_pending()  # samples queued before the ACK belong to the old stream, not this session
            self._write(SAFE_COMMAND)  # arms the watchdog; in lockstep mode it produces the first sample
            pace.start()
            t0 = time.perf_counter()
            try:
                self._cycles(pace)
                if self.supervisor.tripped:
                    s.note_trip_gap()
            except Exception as e:  # a controller, estimator or sink bug: the safe state and ESTOP, said so
                log.exception("the loop failed at t=%.3f s", s.t_s)
                self.supervisor.trip(s.t_s, "software_fault", f"{type(e).__name__}: {e}")
            finally:
                s.wall_s = time.perf_counter() - t0
                s.ran_s = (s.index + 1) * s.period_s
        finally:
            if realtime:
                realtime_teardown()
            self._shutdown()
        return self._result(pace, rt, duration_s)

    def _cycles(self, pace: DevicePacing | HostPacing) -> None:
        """The loop: wait and take, judge, control, write; the rest after the write. Each check once."""
        s, sup, mail = self.run_state, self.supervisor, self.mail
        while (timeout := pace.wait()) is not None:
            if mail is not None:
                mail.check(self)
            taken = self._take_arrived(timeout)
            if taken == 0 and self._host_clock and sup.silent_beyond_budget(time.perf_counter()):
                taken = self._take_arrived(0.0)  # a host stalled in its wait: what came meanwhile is no silence
            t_s = pace.t_s()
            if self._stop_reason:
                sup.trip(t_s, self._stop_kind, self._stop_reason)
            if taken == 0:  # real time: silence on the host clock; virtual time: empty waits in a row
                self._check_reboot()  # an unsolicited HELLO without a sample after it
                sup.no_sample(t_s, time.perf_counter() if self._host_clock else None)
                if sup.tripped:
                    return
                self._write(s.command)  # nothing new: repeat the last command (a lockstep device needs a
                pace.empty()  # COMMAND to produce a SAMPLE; the link-loss count guards this)
                continue
            if sup.tripped:
                return
            state = s.state
            assert state is not None
            cmd = sup.admit(t_s, self.controller(t_s, state))  # clamped, or the safe command once tripped
            self._write(cmd)
            if sup.tripped:  # admitting it tripped (heating, temperature), or the write failed
                return
            self._after_write(t_s, state, cmd)
            pace.controlled(taken)

    # ---- before the write: the samples ---------------------------------------------------------
    def _take_arrived(self, first_timeout: float) -> int:
        """Take every sample that has arrived (waiting up to ``first_timeout`` for the first one);
        each is estimated and supervised, its record waits for the write. Returns how many."""
        hw = self.hw
        n = 0
        try:
            arrival = hw.read(first_timeout)
            while arrival is not None:
                self._take(arrival)
                n += 1
                # a backlog (a device that sent a burst while this process could not run) is taken at most
                # MAX_TAKEN at a time: a loop that kept taking while the device kept sending would never write
                arrival = hw.read(0.0) if n < MAX_TAKEN and hw.pending_samples() else None
        except HardwareError as e:
            self.supervisor.trip(self.run_state.t_s, "link_loss", str(e))
        return n

    def _take(self, arrival: Arrival) -> None:
        """One sample: its place on the device-time axis, its estimate, the supervisor's look at it."""
        s, sup = self.run_state, self.supervisor
        host_time_s, smp, gap = arrival
        if self.hw.stats.reboots != s.reboots_seen:
            self._check_reboot()
        s.sample_gaps += gap
        s.index += gap + 1
        s.samples += 1
        s.final = smp
        s.arrival_s = host_time_s
        t_s = s.index * s.period_s
        state = s.state = self.estimator.update(smp.encoder_count, smp.device_time_us, (smp.adc0, smp.adc1))
        sup.observe(t_s, state, smp.faults, smp.status, host_time_s)
        s.pending.append(_new_record(SampleRecord, (host_time_s, t_s, smp, state,
                                                    SAFE_COMMAND if sup.tripped else s.command, s.command_seq,
                                                    sup.temperature_c)))

    def _check_reboot(self) -> None:
        """React once to each device restart the hardware interface counted (it alone judges them)."""
        s, n = self.run_state, self.hw.stats.reboots
        if n != s.reboots_seen:
            s.reboots += n - s.reboots_seen
            s.reboots_seen = n
            self.estimator.reset()
            self.supervisor.reboot(s.t_s, self.hw.last_reboot or "device restarted")

    def _write(self, cmd: Command) -> None:
        s = self.run_state
        d0, d1 = cmd.duty
        try:
            s.command_seq = self.hw.write_command(d0, d1, cmd.direction, cmd.enable)
            s.wrote(time.perf_counter())
        except HardwareError as e:
            self.supervisor.trip(s.t_s, "link_loss", f"write failed: {e}")
        s.command = cmd

    # ---- after the write -----------------------------------------------------------------------
    def _after_write(self, t_s: float, state: State, cmd: Command) -> None:
        """The command is out: the reaction time, the controller's integration ahead, the records."""
        now = time.perf_counter()
        s = self.run_state
        s.reaction.add(now - s.arrival_s)
        if self._advance is not None:
            self._advance()
        s.cycles += 1
        step = self._last_step() if self._last_step is not None else (-1, math.nan, math.nan, 0.0)
        self.outlet.cycle(s.pending, _new_record(CommandRecord, (now, t_s, cmd, s.command_seq,
                                                                 self.supervisor.temperature_c, *step)))
        s.pending = []
        if s.cycles % STALL_MARK_EVERY == 0:
            s.wait_mark = (time.perf_counter(), run_queue_wait_s())  # a host stall's baseline (_note_trip_gap)

    def _hand_over(self) -> None:
        """Samples taken in a cycle that ended before its write, to the outlet."""
        s = self.run_state
        if s.pending:
            self.outlet.cycle(s.pending, None)
            s.pending = []

    # ---- the end -------------------------------------------------------------------------------
    def _shutdown(self) -> None:
        shut_down(self)

    def _result(self, pace: DevicePacing | HostPacing, rt: RealtimeReport | None, duration_s: float) -> LoopReport:
        s, sup = self.run_state, self.supervisor
        return LoopReport(
            pacing=pace.name, realtime=rt, duration_s=duration_s, cycles=s.cycles, samples=s.samples,
            sample_gaps=s.sample_gaps, reboots=s.reboots, timing={**pace.timing(), **s.speed()},
            reaction=s.reaction.summary(), ran_s=s.ran_s, link=self.hw.stats.as_dict(), events=list(sup.events),
            stall_facts=stall_facts(self, self._host_clock), pwm_unconfirmed=s.pwm_unconfirmed, final_sample=s.final,
            thermal_changes=list(sup.thermal_changes),
            stop_reason=f"safety trip: {sup.events[0].reason}" if sup.events else "duration reached")


def _configure_timeout_s(lockstep: bool, sample_timeout_s: float | None, device_process: object) -> float:
    """How long the session's CONFIGURE may wait for its ACK: a sample's allowance in virtual time, the
    machine's scheduling allowance for a local simulated device, a board's answer time otherwise."""
    if lockstep:
        return max(CONFIGURE_TIMEOUT_S, sample_timeout_s or 0.0)
    return LOCAL_DEVICE_CONFIGURE_TIMEOUT_S if device_process is not None else CONFIGURE_TIMEOUT_S
