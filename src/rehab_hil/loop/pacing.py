"""The loop's state in one place (``RunState``) and its two pacings: the device's sample stream as the clock
(``DevicePacing``), or the host's deadlines (``HostPacing``; docs/loop.md, "Pacing")."""

from __future__ import annotations

import time

from rehab_hil.loop.controllers import SAFE_COMMAND, Command
from rehab_hil.loop.estimation import State
from rehab_hil.loop.records import SampleRecord
from rehab_hil.loop.timing import DeadlineTimer, TimingStats, run_queue_wait_s
from rehab_hil.protocol import Sample

__all__ = ["PACINGS", "RECENT_GAP_S", "DevicePacing", "HostPacing", "RunState"]

RECENT_GAP_S = 1.0  # a gap between two commands this recent can explain a watchdog trip (trip_cause.py)
PACINGS = ("device", "host")


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

    def wrote(self, now: float) -> None:
        """A command went out at ``now``: the longest gap between two writes lately (a host stall shows here)."""
        gap = now - self.last_write_s if self.last_write_s else 0.0
        if gap > self.write_gap_s or now - self.write_gap_end_s > RECENT_GAP_S:
            self.write_gap_s, self.write_gap_end_s = gap, now
        self.last_write_s = now

    def note_trip_gap(self) -> None:
        """The loop returns at once after a trip: its longest gap between commands lately, and how
        much of it the loop thread waited for a CPU (the rest it was blocked: the GIL, I/O)."""
        now = time.perf_counter()
        recent = self.write_gap_s if now - self.write_gap_end_s <= RECENT_GAP_S else 0.0
        self.trip_gap_s = max(now - self.last_write_s, recent)
        if self.wait_mark[0] and now - self.wait_mark[0] <= RECENT_GAP_S + self.trip_gap_s:
            self.trip_cpu_wait_s = min(run_queue_wait_s() - self.wait_mark[1], self.trip_gap_s)

    def speed(self) -> dict[str, float]:
        """Device time the samples covered against the host time the cycles took: 1x in real time, the
        speed-up of a lockstep run (issue 25: at least 5x over a pty)."""
        device_s = (self.samples + self.sample_gaps) * self.period_s
        return {"wall_s": self.wall_s, "device_s": device_s,
                "speed_x": device_s / self.wall_s if self.wall_s > 0 else 0.0}


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
