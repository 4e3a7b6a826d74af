"""The loop's end: PWM 0 at once; after a trip ESTOP and the events to every sink, then samples watched
until one shows the PWM off (or why none could); and what the loop knows of stalls for the trip's cause."""

from __future__ import annotations

import time
from typing import TYPE_CHECKING

from rehab_hil.hardware.interface import Arrival, HardwareError, LifecycleState
from rehab_hil.loop.controllers import SAFE_COMMAND
from rehab_hil.loop.records import EventRecord
from rehab_hil.loop.trip_cause import StallFacts, pwm_unconfirmed_text
from rehab_hil.protocol import Status

if TYPE_CHECKING:
    from rehab_hil.loop.runner import LoopService

__all__ = ["CONFIRM_CYCLES", "CONFIRM_S", "shut_down", "stall_facts"]

CONFIRM_CYCLES = 20  # cycles spent after a trip confirming the device reports PWM 0
CONFIRM_S = 0.5  # ... and at least this long (host clock) while no sample shows it


def shut_down(loop: LoopService) -> None:
    """PWM 0 now; after a trip also ESTOP, then watch a few samples confirm PWM off. Nothing to
    do on a device that was never configured (its CONFIGURE failed): it is not driving."""
    s, sup = loop.run_state, loop.supervisor
    loop._hand_over()  # samples taken in a cycle that ended before its write
    s.command = SAFE_COMMAND
    if loop.hw.state is not LifecycleState.ACTIVE:
        return
    loop._write(SAFE_COMMAND)
    if sup.tripped:  # to every sink: recorded, published on zenoh's .../safety, shown
        loop.outlet.events([EventRecord(ev.t_s, ev.reason, ev.detail) for ev in sup.events])
        if sup.events[0].reason not in ("link_loss",):
            try:
                loop.hw.estop(timeout=0.5)
            except HardwareError as e:
                sup.trip(s.t_s, "estop_unanswered", str(e))
    _confirm_pwm_off(loop)


def _confirm_pwm_off(loop: LoopService) -> None:
    """Watch the samples until one shows every PWM off, writing PWM 0 each time (a lockstep
    device answers each COMMAND with a SAMPLE), for ``CONFIRM_CYCLES`` and at least ``CONFIRM_S``
    of host time (on a busy machine a simulated device's echo takes tens of ms). None showing
    it: "NO" only if the device echoed the PWM-0 command and still drives; else unconfirmed, and why."""
    s, sup = loop.run_state, loop.supervisor
    watchdog_ms = float(loop.configure_msg.watchdog_ms)
    if sup.events and sup.events[0].reason == "link_loss":
        s.pwm_unconfirmed = pwm_unconfirmed_text("the link was lost: no sample came after the trip", watchdog_ms)
        return
    end, n = time.perf_counter() + CONFIRM_S, 0
    while n < CONFIRM_CYCLES or time.perf_counter() < end:
        n += 1
        loop._write(SAFE_COMMAND)
        try:
            arrival = loop.hw.read(timeout=2 * loop.period_s)
        except HardwareError:
            break
        if arrival is not None:
            _take_quiet(loop, arrival)
        f = s.final
        if f is not None and ((f.duty0 == 0 and f.duty1 == 0 and not f.status & Status.PWM_ENABLED)
                              or (arrival is not None and f.cmd_seq_echo == s.command_seq)):
            return  # off, or the PWM-0 command applied and still driving: a real NO
    waited = time.perf_counter() - end + CONFIRM_S
    s.pwm_unconfirmed = pwm_unconfirmed_text(f"no sample within {waited:.2f} s showed the PWM-0 command applied",
                                             watchdog_ms)


def _take_quiet(loop: LoopService, arrival: Arrival) -> None:
    """A sample during shutdown: recorded and counted, no more trips judged."""
    n_events = len(loop.supervisor.events)
    loop._take(arrival)
    loop.supervisor.forget_events(n_events)
    loop._hand_over()


def stall_facts(loop: LoopService, host_clock: bool) -> StallFacts:
    """What the loop knows of stalls at the end (the device asked for its own count once)."""
    s, sup, proc = loop.run_state, loop.supervisor, getattr(loop.hw, "device_process", None)
    reported = proc.reported_stalls() if proc is not None and host_clock and proc.alive() else {}
    return StallFacts(float(loop.configure_msg.watchdog_ms), s.trip_gap_s, list(sup.device_stalls), reported,
                      simulated=proc is not None, host_cpu_wait_s=s.trip_cpu_wait_s)
