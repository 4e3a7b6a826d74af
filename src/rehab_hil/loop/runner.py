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

from rehab_hil.hardware.interface import Arrival, HardwareError, HardwareInterface, LifecycleState
from rehab_hil.loop.controllers import SAFE_COMMAND, Command, LoopController
from rehab_hil.loop.estimation import Estimator, State
from rehab_hil.loop.records import CommandRecord, EventRecord, SampleRecord
from rehab_hil.loop.supervisor import SafetyEvent, Supervisor
from rehab_hil.loop.thermal import ThermalTightening
from rehab_hil.loop.timing import (
    HELPER_NICE,
    DeadlineTimer,
    RealtimeReport,
    TimingStats,
    realtime_setup,
    realtime_teardown,
    run_queue_wait_s,
)
from rehab_hil.loop.trip_cause import StallFacts, pwm_unconfirmed_text
from rehab_hil.protocol import Configure, Sample, Status

__all__ = ["PACINGS", "LoopReport", "LoopService", "Outlet", "RunState"]

log = logging.getLogger(__name__)
# tuple.__new__ builds a record NamedTuple without its generated Python-level __new__ (as its _make
# does): half the cost, once per sample and per command on the loop thread
_new_record = tuple.__new__

CONFIRM_CYCLES = 20  # cycles spent after a trip confirming the device reports PWM 0
CONFIRM_S = 0.5  # ... and at least this long (host clock) while no sample shows it
STALL_MARK_EVERY = 50  # cycles between marks of the loop thread's run-queue wait (a host stall's baseline)
RECENT_GAP_S = 1.0  # a gap between two commands this recent can explain a watchdog trip (trip_cause.py)
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


class RunState:
    """One run's state, in one place: the device-time axis, the counts, what is in force, the
    records waiting for the write and the per-cycle figures (preallocated)."""

    def __init__(self, period_s: float, n_max: int, reboots_seen: int) -> None:
        self.period_s, self.n_max = period_s, n_max
        self.index = -1  # continued sample index of the newest sample taken (gaps included): device time
        self.samples = 0  # samples taken: estimated, supervised, recorded
        self.sample_gaps = 0  # samples missing before those taken (as the hardware interface judged them)
        self.reboots = 0  # device restarts in this session (the interface's count)
        self.reboots_seen = reboots_seen  # the interface's count when last looked at
        self.cycles = 0  # control cycles: a command computed from a sample and written
        self.coalesced = 0  # samples taken in a cycle that controlled a newer one
        self.state: State | None = None  # estimate of the newest sample
        self.final: Sample | None = None  # the newest sample
        self.command: Command = SAFE_COMMAND  # the last command written
        self.command_seq = -1  # its COMMAND seq
        self.pending: list[SampleRecord] = []  # records of the samples taken, handed over after the write
        self.reaction = TimingStats(n_max)  # sample arrival -> command written
        self.arrival_s = 0.0  # host clock when the newest sample arrived (perf_counter)
        self.last_write_s = 0.0  # host clock of the last command written
        self.write_gap_s = self.write_gap_end_s = 0.0  # the longest gap between two writes lately, and its end
        self.trip_gap_s = 0.0  # host clock from the last command written to the trip (a host stall shows here)
        self.trip_cpu_wait_s = 0.0  # of it, the loop thread runnable but waiting for a CPU
        self.wait_mark = (0.0, 0.0)  # (host clock, the loop thread's run-queue wait) at the last progress update
        self.pwm_unconfirmed = ""  # why no sample after a trip shows the PWM state
        self.wall_s = 0.0  # host time the cycles took (a lockstep run's speed: device time / this)
        self.ran_s = 0.0  # device time covered when the loop stopped (before the shutdown's samples)

    @property
    def t_s(self) -> float:
        """Device time of the newest sample (0 before the first)."""
        return max(self.index, 0) * self.period_s


class DevicePacing:
    """The device's sample stream is the clock: a cycle starts when a sample arrives (waiting up to
    ``timeout_s``), takes every sample that came with it and controls the newest; its time is that
    sample's device time. An empty wait counts as one period towards the session's length."""

    name = "device"

    def __init__(self, run_state: RunState, timeout_s: float) -> None:
        self.run_state, self.timeout_s = run_state, timeout_s
        self.k = 0  # cycles of the session's length used up

    def start(self) -> None:
        pass

    def wait(self) -> float | None:
        """How long this cycle may wait for its first sample, or None when the session's length is reached."""
        return self.timeout_s if self.k < self.run_state.n_max else None

    def t_s(self) -> float:
        s = self.run_state
        return (s.index if s.index >= 0 else self.k) * s.period_s

    def controlled(self, taken: int) -> None:
        self.run_state.coalesced += taken - 1
        self.k = self.run_state.index + 1

    def empty(self) -> None:
        self.k += 1

    def timing(self) -> dict[str, float]:
        """Reaction percentiles; missed cycles are the samples not controlled: coalesced or lost."""
        s = self.run_state
        out = s.reaction.summary()
        missed = s.coalesced + s.sample_gaps
        out["missed_cycles"] = float(missed)
        out["coalesced_samples"] = float(s.coalesced)
        out["missed_pct"] = 100.0 * missed / (s.cycles + missed) if s.cycles + missed else 0.0
        return out


class HostPacing:
    """The host's clock: a cycle wakes on the deadline t0 + k x period (``DeadlineTimer``) and takes
    whatever arrived, without waiting; its time is k x period. Missed cycles are skipped deadlines."""

    name = "host"

    def __init__(self, run_state: RunState) -> None:
        self.run_state = run_state
        self.timer = DeadlineTimer(run_state.period_s, run_state.n_max)
        self.k = 0

    def start(self) -> None:
        self.timer.start()

    def wait(self) -> float | None:
        """Sleep to this cycle's deadline; then take what arrived without waiting (0), or None at the end."""
        self.k = self.timer.wait()
        return 0.0 if self.k < self.run_state.n_max else None

    def t_s(self) -> float:
        return self.k * self.run_state.period_s

    def controlled(self, taken: int) -> None:
        self.run_state.coalesced += taken - 1

    def empty(self) -> None:
        pass

    def timing(self) -> dict[str, float]:
        return self.timer.stats.summary()


PACINGS = ("device", "host")


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
                    self._note_trip_gap()
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
    def _note_trip_gap(self) -> None:
        """The loop returns at once after a trip: its longest gap between commands lately, and how
        much of it the loop thread waited for a CPU (the rest it was blocked: the GIL, I/O)."""
        s = self.run_state
        now = time.perf_counter()
        recent = s.write_gap_s if now - s.write_gap_end_s <= RECENT_GAP_S else 0.0
        s.trip_gap_s = max(now - s.last_write_s, recent)
        if s.wait_mark[0] and now - s.wait_mark[0] <= RECENT_GAP_S + s.trip_gap_s:
            s.trip_cpu_wait_s = min(run_queue_wait_s() - s.wait_mark[1], s.trip_gap_s)

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
                arrival = hw.read(0.0) if hw.pending_samples() else None
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
            now = time.perf_counter()
            gap = now - s.last_write_s if s.last_write_s else 0.0
            if gap > s.write_gap_s or now - s.write_gap_end_s > RECENT_GAP_S:  # a host stall shows here
                s.write_gap_s, s.write_gap_end_s = gap, now
            s.last_write_s = now
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
        """PWM 0 now; after a trip also ESTOP, then watch a few samples confirm PWM off. Nothing to
        do on a device that was never configured (its CONFIGURE failed): it is not driving."""
        s, sup = self.run_state, self.supervisor
        self._hand_over()  # samples taken in a cycle that ended before its write
        s.command = SAFE_COMMAND
        if self.hw.state is not LifecycleState.ACTIVE:
            return
        self._write(SAFE_COMMAND)
        if sup.tripped:  # to every sink: recorded, published on zenoh's .../safety, shown
            self.outlet.events([EventRecord(ev.t_s, ev.reason, ev.detail) for ev in sup.events])
            if sup.events[0].reason not in ("link_loss",):
                try:
                    self.hw.estop(timeout=0.5)
                except HardwareError as e:
                    sup.trip(s.t_s, "estop_unanswered", str(e))
        self._confirm_pwm_off()

    def _confirm_pwm_off(self) -> None:
        """Watch the samples until one shows every PWM off, writing PWM 0 each time (a lockstep
        device answers each COMMAND with a SAMPLE), for ``CONFIRM_CYCLES`` and at least ``CONFIRM_S``
        of host time (on a busy machine a simulated device's echo takes tens of ms). None showing
        it: "NO" only if the device echoed the PWM-0 command and still drives; else unconfirmed, and why."""
        s, sup = self.run_state, self.supervisor
        watchdog_ms = float(self.configure_msg.watchdog_ms)
        if sup.events and sup.events[0].reason == "link_loss":
            s.pwm_unconfirmed = pwm_unconfirmed_text("the link was lost: no sample came after the trip", watchdog_ms)
            return
        end, n = time.perf_counter() + CONFIRM_S, 0
        while n < CONFIRM_CYCLES or time.perf_counter() < end:
            n += 1
            self._write(SAFE_COMMAND)
            try:
                arrival = self.hw.read(timeout=2 * self.period_s)
            except HardwareError:
                break
            if arrival is not None:
                self._take_quiet(arrival)
            f = s.final
            if f is not None and ((f.duty0 == 0 and f.duty1 == 0 and not f.status & Status.PWM_ENABLED)
                                  or (arrival is not None and f.cmd_seq_echo == s.command_seq)):
                return  # off, or the PWM-0 command applied and still driving: a real NO
        waited = time.perf_counter() - end + CONFIRM_S
        s.pwm_unconfirmed = pwm_unconfirmed_text(f"no sample within {waited:.2f} s showed the PWM-0 command applied",
                                                 watchdog_ms)

    def _take_quiet(self, arrival: Arrival) -> None:
        """A sample during shutdown: recorded and counted, no more trips judged."""
        n_events = len(self.supervisor.events)
        self._take(arrival)
        self.supervisor.forget_events(n_events)
        self._hand_over()

    def _stall_facts(self) -> StallFacts:
        """What the loop knows of stalls at the end (the device asked for its own count once)."""
        s, sup, proc = self.run_state, self.supervisor, getattr(self.hw, "device_process", None)
        reported = proc.reported_stalls() if proc is not None and self._host_clock and proc.alive() else {}
        return StallFacts(float(self.configure_msg.watchdog_ms), s.trip_gap_s, list(sup.device_stalls), reported,
                          simulated=proc is not None, host_cpu_wait_s=s.trip_cpu_wait_s)

    def _result(self, pace: DevicePacing | HostPacing, rt: RealtimeReport | None, duration_s: float) -> LoopReport:
        s, sup = self.run_state, self.supervisor
        return LoopReport(
            pacing=pace.name, realtime=rt, duration_s=duration_s, cycles=s.cycles, samples=s.samples,
            sample_gaps=s.sample_gaps, reboots=s.reboots, timing={**pace.timing(), **_speed(s)},
            reaction=s.reaction.summary(), ran_s=s.ran_s, link=self.hw.stats.as_dict(), events=list(sup.events),
            stall_facts=self._stall_facts(), pwm_unconfirmed=s.pwm_unconfirmed, final_sample=s.final,
            thermal_changes=list(sup.thermal_changes),
            stop_reason=f"safety trip: {sup.events[0].reason}" if sup.events else "duration reached")


def _configure_timeout_s(lockstep: bool, sample_timeout_s: float | None, device_process: object) -> float:
    """How long the session's CONFIGURE may wait for its ACK: a sample's allowance in virtual time, the
    machine's scheduling allowance for a local simulated device, a board's answer time otherwise."""
    if lockstep:
        return max(CONFIGURE_TIMEOUT_S, sample_timeout_s or 0.0)
    return LOCAL_DEVICE_CONFIGURE_TIMEOUT_S if device_process is not None else CONFIGURE_TIMEOUT_S


def _speed(s: RunState) -> dict[str, float]:
    """Device time the samples covered against the host time the cycles took: 1x in real time, the
    speed-up of a lockstep run (issue 25: at least 5x over a pty)."""
    device_s = (s.samples + s.sample_gaps) * s.period_s
    return {"wall_s": s.wall_s, "device_s": device_s, "speed_x": device_s / s.wall_s if s.wall_s > 0 else 0.0}
