"""Whose stall a watchdog or link-loss trip was, and how long, in one line with a hint.

The device's watchdog exists to catch the host: a loop that wrote no command for the watchdog's
length stalled (its process was not scheduled). A link loss with the host running is the link's or
the device's; with a local simulated device the host also knows whether that process could run
(``devices/starvation.py``) and what stalls it reported itself (``devices/stall.py``). Other trips
(limits, e-stop) are no stall: their cause is their detail.
"""

from __future__ import annotations

from dataclasses import dataclass, field

from rehab_hil.loop.supervisor import DeviceStall, SafetyEvent

__all__ = ["HINT", "StallFacts", "explain", "pwm_unconfirmed_text"]

HINT = ("hint: on a busy machine or in CI run with --lockstep (virtual time: neither side can stall); "
        "docs/loop.md, 'Scheduling'")
HOST_SHARE = 0.8  # a write gap this share of the watchdog or more: the host starved the watchdog


@dataclass
class StallFacts:
    """What the loop knows at the end: the host's gap between its last command and the trip, the
    device watchdog's length, the silences the local device's process could not run, and the
    stalls that device reported itself (``not_scheduled*`` fields of its status; empty: none told)."""

    watchdog_ms: float
    host_gap_s: float = 0.0
    device_stalls: list[DeviceStall] = field(default_factory=list)
    device_reported: dict[str, float] = field(default_factory=dict)
    simulated: bool = False  # a local simulated device (its process can be starved)
    host_cpu_wait_s: float = 0.0  # of the host's gap, its loop thread runnable but waiting for a CPU


def _device_said(f: StallFacts) -> str:
    rep = f.device_reported
    n = int(rep.get("not_scheduled", 0))
    if not rep:
        return ""
    if not n:
        return "; the simulated device reported no stall of its own"
    return (f"; the simulated device reported {n} stall(s) of its own process, longest "
            f"{rep.get('not_scheduled_max_ms', 0.0):.1f} ms")


def explain(ev: SafetyEvent, f: StallFacts) -> str:
    """The cause line of one trip ("" for a trip that is no stall)."""
    if ev.reason == "device_fault" and "WATCHDOG" in ev.detail.split("+"):
        gap_ms = f.host_gap_s * 1e3
        if gap_ms >= HOST_SHARE * f.watchdog_ms:
            wait_ms = f.host_cpu_wait_s * 1e3
            return (f"host stall: the host loop wrote no command for {gap_ms:.1f} ms (device watchdog "
                    f"{f.watchdog_ms:.0f} ms); its thread waited {wait_ms:.1f} ms of it for a CPU and was blocked "
                    f"the rest (another host thread holding the GIL, or I/O){_device_said(f)}; {HINT}")
        who = "the simulated device" if f.simulated else "the device"
        return (f"not a host stall (its longest gap between commands in the last second: {gap_ms:.1f} ms): the "
                f"commands did not reach {who} in time (the link, or {who}){_device_said(f)}; {HINT}")
    if ev.reason == "link_loss":
        if "exited" in ev.detail:
            return f"the device process exited: no stall{_device_said(f)}"
        if f.simulated:
            return (f"not a host stall (the host waited for samples); the simulated device sent none while its "
                    f"process could run{_device_said(f)}; {HINT}")
        return f"not a host stall (the host waited for samples): the link or the device; {HINT}"
    return ""


def pwm_unconfirmed_text(why: str, watchdog_ms: float) -> str:
    """Why a session's last PWM state is unconfirmed (no sample after the PWM-0 command shows it)."""
    return (f"unconfirmed: {why}; the host sent PWM 0, and the device's own watchdog turns the PWM off "
            f"{watchdog_ms:.0f} ms after the last command it received")
