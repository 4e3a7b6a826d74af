"""Fault injection across the stack (PX4-style): a real session of the loop service against a
real simulated device on a pty, with one fault injected mid-session.

Faults come from the device's own knobs (frames dropped, corrupted, delayed, truncated, garbage,
stall, exit, reboot) or from ``LinkProxy`` between host and device (single bytes dropped, single
bits flipped in both directions, a one-way stall, the cable pulled), or from the host itself (the
loop paused 200 ms). For every fault:

- the device's PWM is never on longer than the watchdog after the last COMMAND it applied, and
  never on while a fault is latched (checked on the device's own output, tapped before the fault,
  in device time);
- the host never crashes: ``LoopService.run`` returns; it counts what it lost and, where the fault
  is documented to stop a session (docs/safety.md), trips with that reason, logs it and records
  it as an MCAP event;
- the recording stays readable and holds every sample the host received, no more, no less.
"""

from __future__ import annotations

import dataclasses
import logging
import math
import os
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np
import pytest

from rehab_hil.interchange import read_csv
from rehab_hil.loop.controllers import Command, ControllerRuntime
from rehab_hil.loop.estimation import State
from rehab_hil.loop.recorder import Recorder, read_mcap
from rehab_hil.loop.result import RunResult
from rehab_hil.protocol import Fault
from rehab_hil.service import assembly
from rehab_hil.service.session import open_session
from rehab_hil.testing import pid_runtime

from .conftest import CONFIG
from .link_proxy import LinkProxy

pytestmark = [pytest.mark.slow, pytest.mark.timeout(120)]

FAULT_AT_S = 0.3  # session time of the injection
DURATION_S = 1.0
# A session whose fault must end it runs until it does (the trip ends it; 30 s caps a missing trip):
# a knob travels to the device through a pipe off the loop thread, and beside two busy loops a
# reboot knob arrived after a 1 s session had ended (the host saw no reboot: events []).
TRIP_DURATION_S = 30.0
SAMPLE_TIMEOUT_S = 0.05  # a cycle waits this long for its sample; the link-loss budget is set in run_session
# The rig's watchdog is 50 ms (configs/finger_extensor.toml). On a loaded 2-core box the chain
# host -> proxy -> (USB-bridge model) -> device is starved for far longer than that: beside two busy
# loops and other test runs (issue 25, load 10-17) host-side gaps without a sample of 1.00-1.04 s
# tripped the former 1 s link budget before and after the fault, a 1 s device watchdog on both
# backends, and a 300 ms one before a host stall or an unplug was injected; the worst gap in a case
# that had no stall of its own was 1.46 s (CSV host_time_s, printed per case as worst_host_gap)
# over 5 runs of this file at that load. STARVATION_BUDGET_S covers them with a margin: it is
# the link-loss budget of every session and the device watchdog of every session (the watchdog is
# not what most cases test; the device-time bound checked below is the configured watchdog,
# whatever its value). A one-way stall outlasts it by 2 s. The host stall lasts until the device's
# watchdog has cut the PWM in the device's own time (seen on the tap): the firmware in simavr runs
# slower than real time under load (a 4 s stall was 2.28 s of its time), so no fixed stall is long
# enough on every backend; the link budget of that case also covers the stall itself.
STARVATION_BUDGET_S = 3.0
WATCHDOG_TOLERANT_MS = int(STARVATION_BUDGET_S * 1000)
STALL_S = STARVATION_BUDGET_S + 2.0
DEVICE_TIME_WAIT_S = 60.0  # cap on waits for the device to reach a watchdog in its own time (slow under load)


class Hooked:
    """The session's real controller, plus one action run when session time first reaches ``at_s``
    (in the loop thread: a host stall blocks it, a knob returns at once)."""

    def __init__(self, inner: Any, at_s: float, action: Callable[[], None]) -> None:
        self.inner, self.at_s, self.action, self.fired_at = inner, at_s, action, None
        self.claims = inner.claims

    def reset(self) -> None:
        self.inner.reset()

    def __call__(self, t_s: float, state: State) -> Command:
        if self.fired_at is None and t_s >= self.at_s:
            self.fired_at = t_s
            self.action()
        return self.inner(t_s, state)


def gentle_pid(cfg: Any) -> ControllerRuntime:
    """A PID that keeps the PWM on (a slow sine reference) at a few % duty: the motor moves under
    100 deg/s, so a host that lags 100+ ms on a loaded box (or a 1 s watchdog) cannot carry the iris
    out of its range of motion, and a shared device starts every test inside its range."""
    return pid_runtime(cfg, sine=(30.0, 20.0, 0.5), gains=(0.05, 0.0, 0.0, 0.0))


@dataclass
class Ctx:
    device: Any
    proxy: LinkProxy
    hw: Any

    knobs: threading.Thread | None = None
    conf: Any = None  # the session's CONFIGURE

    def knob(self, *lines: str) -> None:
        """Device control commands, in order, off the loop thread (each reply takes a pipe round trip);
        ``settle()`` waits for them. A device that exits on ``disconnect`` answers nothing: ignored."""

        def send() -> None:
            for line in lines:
                try:
                    self.device.control(line)
                except Exception:  # the device is gone (disconnect): the test checks the host's view
                    return

        self.knobs = threading.Thread(target=send, daemon=True)
        self.knobs.start()

    def settle(self) -> None:
        if self.knobs is not None:
            self.knobs.join(timeout=10)


@dataclass(frozen=True)
class Scenario:
    name: str
    inject: Callable[[Ctx], None]
    trip: str | None  # the supervisor's first reason, None: the session must run to its end
    watchdog_ms: int = WATCHDOG_TOLERANT_MS
    link_budget_s: float = STARVATION_BUDGET_S  # host time without a sample before the host trips link_loss
    check: Callable[[RunResult, Ctx], None] = lambda res, ctx: None
    avr: bool = True  # the fault can be injected on the firmware in simavr too (no Python-device knob needed)


def _host_bad_frames(res: RunResult, ctx: Ctx) -> None:
    assert sum(res.link["bad_frames"].values()) >= 1, res.link


def _gaps_and_bad(res: RunResult, ctx: Ctx) -> None:
    _host_bad_frames(res, ctx)
    assert res.sample_gaps >= 1


def _both_directions(res: RunResult, ctx: Ctx) -> None:
    _gaps_and_bad(res, ctx)
    if ctx.proxy.up.injected["flipped_bits"]:  # the device counted the commands it dropped (tapped SAMPLEs)
        wait_for(lambda: device_rx_bad(ctx) > ctx.proxy.device_tap.samples[0].rx_bad_frames)


def device_rx_bad(ctx: Ctx) -> int:
    """The device's own count of bad frames received, from the last SAMPLE it sent."""
    last = ctx.proxy.device_tap.last
    return last.rx_bad_frames if last is not None else 0


def _delayed(res: RunResult, ctx: Ctx) -> None:
    assert res.link["latency_p99_s"] >= 0.010  # command -> echo crosses the 5 ms delay twice


def _device_dropped(res: RunResult, ctx: Ctx) -> None:
    assert res.sample_gaps >= 1


def _device_watchdog_seen(ctx: Ctx) -> bool:
    last = ctx.proxy.device_tap.last
    return last is not None and bool(last.faults & Fault.WATCHDOG)


def _stall_host_until_the_device_watchdog(ctx: Ctx) -> None:
    """The loop paused (in its thread) until the device, in its own time, has latched WATCHDOG."""
    wait_for(lambda: _device_watchdog_seen(ctx), DEVICE_TIME_WAIT_S)


def _watchdog_latched(res: RunResult, ctx: Ctx) -> None:
    assert "WATCHDOG" in res.events[0].detail
    tap = ctx.proxy.device_tap
    # reported in a FAULT frame, unless the device's output was lost right there before the tap
    # (series 7, run 5: a starved proxy, 7 damaged frames from the device, the report among them)
    reported = any(r.faults & Fault.WATCHDOG for r in tap.fault_reports)
    hidden = [whole for bits, whole in tap.unreported_trips if bits & Fault.WATCHDOG]
    assert reported or (hidden and not any(hidden)), (tap.fault_reports, tap.unreported_trips)


def _pwm_off_on_device_after_unplug(res: RunResult, ctx: Ctx) -> None:
    wait_for(lambda: _device_watchdog_seen(ctx), DEVICE_TIME_WAIT_S)
    last = ctx.proxy.device_tap.last
    assert last is not None and (last.duty0, last.duty1) == (0, 0)


def _rebooted(res: RunResult, ctx: Ctx) -> None:
    assert res.reboots >= 1 and ctx.hw.stats.reboots >= 1
    # the rebooted device is unconfigured (PWM off by construction) and the host latched an ESTOP on it
    ctx.hw.configure(ctx.conf)
    ctx.hw.discard_pending()
    s = ctx.hw.read_sample(timeout=2.0)
    assert s is not None and (s.duty0, s.duty1) == (0, 0) and s.faults & Fault.ESTOP_COMMAND


SCENARIOS = [
    Scenario("byte_drop", lambda c: setattr(c.proxy.down, "drop_p", 5e-4), None, check=_gaps_and_bad),
    Scenario("bit_flips_both_ways", lambda c: (setattr(c.proxy.down, "flip_p", 3e-4),
                                               setattr(c.proxy.up, "flip_p", 3e-4)), None, check=_both_directions),
    Scenario("garbage_burst", lambda c: setattr(c.proxy.down, "garbage", 3000), None, check=_host_bad_frames),
    Scenario("truncated_frames", lambda c: setattr(c.proxy.down, "truncate", 5), None, check=_gaps_and_bad),
    Scenario("delayed_frames", lambda c: (setattr(c.proxy.down, "delay_s", 0.005),
                                          setattr(c.proxy.up, "delay_s", 0.005)), None, check=_delayed),
    Scenario("device_drops_frames", lambda c: c.knob("drop 0.02"), None, check=_device_dropped, avr=False),
    Scenario("device_corrupts_frames", lambda c: c.knob("corrupt 0.02"), None, check=_gaps_and_bad, avr=False),
    Scenario("device_garbage_and_truncation", lambda c: c.knob("garbage 500", "truncate"), None,
             check=_host_bad_frames, avr=False),
    Scenario("stalled_device_link", lambda c: c.proxy.stall(c.proxy.down, STALL_S), "link_loss"),
    Scenario("stalled_device_knob", lambda c: c.knob(f"stall {int(STALL_S * 1000)}"), "link_loss", avr=False),
    Scenario("unplug", lambda c: c.proxy.unplug(), "link_loss",
             check=_pwm_off_on_device_after_unplug),
    Scenario("device_reboot", lambda c: c.knob("reboot"), "device_reboot", check=_rebooted),
    Scenario("host_stall", _stall_host_until_the_device_watchdog, "device_fault",
             link_budget_s=DEVICE_TIME_WAIT_S + STARVATION_BUDGET_S,
             check=_watchdog_latched),
    # last: the device is respawned after it
    Scenario("device_exits", lambda c: c.knob("disconnect"), "link_loss", avr=False),
]


def wait_for(pred: Callable[[], Any], timeout: float = 3 * STARVATION_BUDGET_S) -> None:
    deadline = time.monotonic() + timeout
    while not pred():
        assert time.monotonic() < deadline, "condition not met in time"
        time.sleep(0.01)


# The firmware in simavr (harness throttled to real time + plant driver + proxy + host) needs about
# two free cores: on a heavily shared box (load 10+ on 2 vCPUs) its host writes time out and links
# starve, so these cases run one at a time (one xdist group) and can be switched off there with
# RELIABILITY_AVR=0. On a quiet machine they passed 9/9 twice under -n 2 (docs/safety.md).
AVR_OPT_OUT = pytest.mark.skipif(os.environ.get("RELIABILITY_AVR") == "0",
                                 reason="firmware-in-simavr fault cases switched off: RELIABILITY_AVR=0")
# With the Uno's USB bridge model on (issue 16 target: PWM off within the watchdog after any link
# fault, both devices): the link faults on the Python device, and on the firmware the ones that
# end a session (cable pulled, one-way stall, host stall) plus bit flips both ways.
BRIDGED_AVR = ("bit_flips_both_ways", "stalled_device_link", "unplug", "host_stall")
CASES = [pytest.param("python", s, id=f"python-{s.name}") for s in SCENARIOS] + [
    pytest.param("avr", s, id=f"avr-{s.name}",
                 marks=[pytest.mark.firmware, AVR_OPT_OUT, pytest.mark.xdist_group("avr_faults")])
    for s in SCENARIOS if s.avr] + [
    pytest.param("python+bridge", s, id=f"python-bridge-{s.name}", marks=[pytest.mark.xdist_group("bridge_faults")])
    for s in SCENARIOS if s.avr] + [
    pytest.param("avr+bridge", s, id=f"avr-bridge-{s.name}",
                 marks=[pytest.mark.firmware, AVR_OPT_OUT, pytest.mark.xdist_group("avr_faults")])
    for s in SCENARIOS if s.name in BRIDGED_AVR]


# Real time through a pty proxy, by design (link faults are about timing and budgets).
@pytest.mark.parametrize(("backend", "scenario"), CASES)
def test_each_fault_leaves_pwm_off_in_time_is_reported_and_loses_no_received_sample(
        backend: str, scenario: Scenario, link: tuple[Any, LinkProxy, Any], cfg: Any, binding: Any, tmp_path: Any,
        caplog: pytest.LogCaptureFixture) -> None:
    device, proxy, hw = link
    ctx = Ctx(device, proxy, hw)
    res, rec, conf = run_session(ctx, cfg, binding, tmp_path, scenario, caplog)

    # the host: detected, logged, reported, stopped or carried on as documented
    if scenario.trip is None:
        assert res.events == [], res.events
        assert res.stop_reason == "duration reached"
    else:
        assert res.events and res.events[0].reason == scenario.trip, res.events
        assert any("safety trip" in r.getMessage() and scenario.trip in r.getMessage() for r in caplog.records)
        kinds = [m["kind"] for topic, _, m in read_mcap(rec.mcap_path) if topic == "/rig/event"]
        assert scenario.trip in kinds
    scenario.check(res, ctx)

    # the device, in its own time: PWM never on past the watchdog, never on while a fault is latched; a
    # simulated device's ticks caught up after its own process was not scheduled while the host's
    # commands arrived do not count towards its watchdog (sim_device.py: an MCU would have seen them in
    # time), so they extend the bound by what the device reports excused (0 unless it stalled)
    tap = proxy.device_tap
    assert tap.violations == 0
    bound_us = conf.watchdog_ms * 1000 + 1000 + 1000 * device.reported_stalls().get("not_scheduled_excused_ms", 0.0)
    assert tap.worst_on_since_command_us < bound_us, tap.worst_on_since_command_us
    assert all(t <= bound_us for t in tap.pwm_off_after_command_us)
    # an off transition seen across lost samples: the last sample seen on was within the bound (the
    # worst_on check above), the moment of the switch-off itself was not seen
    assert all(on <= bound_us for on, _ in tap.pwm_off_unresolved_us)

    # the recording: readable, every received sample exactly once, in order, CSV == MCAP
    csv = read_csv(rec.csv_path)
    idx = csv["sample_index"].astype(np.int64)
    assert len(idx) == res.samples
    assert set(np.unique(idx)) <= {s.sample_index for s in tap.samples} or scenario.name.startswith("device_")
    mcap_idx = [int(m["sample_index"]) for topic, _, m in read_mcap(rec.mcap_path) if topic == "/rig/sample"]
    assert mcap_idx == list(idx)
    if scenario.trip is None and not scenario.name.startswith("device_"):
        # each sample the host missed is a counted gap: those lost after the tap (the injected fault)
        # and those lost before it (the device's pty full while a loaded machine starved the proxy:
        # the tap never saw them either)
        sent = {s.sample_index for s in tap.samples if idx[0] <= s.sample_index <= idx[-1]}
        holes = int(idx[-1] - idx[0] + 1) - len(idx)
        assert len(sent - set(idx)) <= holes <= res.sample_gaps


def patient_configure(hw: Any) -> None:
    """``hw.configure`` and ``hw.clear`` (the set-up's and ``LoopService.run``'s) wait up to
    STARVATION_BUDGET_S, not 1 s: on the firmware behind the bridge model beside two busy loops 1 s
    went unanswered. A copy lost on the way (a byte the firmware in simavr dropped from its 2-byte
    receive buffer) the host sends again by itself (``SerialHardware._request``). Once per ``hw``:
    the connection is shared by every case."""
    if getattr(hw, "patient", False):
        return
    configure, clear = hw.configure, hw.clear
    hw.configure = lambda conf, timeout=1.0: configure(conf, timeout=max(timeout, STARVATION_BUDGET_S))
    hw.clear = lambda timeout=1.0: clear(timeout=max(timeout, STARVATION_BUDGET_S))
    hw.patient = True


def run_session(ctx: Ctx, cfg: Any, binding: Any, out_dir: Any, scenario: Scenario,
                caplog: pytest.LogCaptureFixture) -> tuple[RunResult, Recorder, Any]:
    # The range of motion open (firmware and host): the shared device's iris starts each case where
    # the last one left it, and with the drive off it relaxes to its rest (-9.5 deg, outside the
    # config's -5 deg end stop: avr-bridge-unplug tripped range_of_motion at its first sample beside
    # two busy loops, after being driven into range, while its CONFIGURE waited). These cases are
    # about link faults; the range checks have their own tests (docs/safety.md).
    conf = dataclasses.replace(assembly.firmware_configure(cfg, binding), watchdog_ms=scenario.watchdog_ms,
                               enc_min=-(1 << 30), enc_max=1 << 30)
    ctx.conf = conf
    patient_configure(ctx.hw)
    controller = Hooked(gentle_pid(cfg), FAULT_AT_S, lambda: scenario.inject(ctx))
    controller.inner(0.0, State(0.0, 0.0, 0.0, {}))  # compile before the device streams
    if ctx.device.kind == "python":  # the shared device: knobs of earlier tests off
        for line in ("drop 0", "corrupt 0", "delay 0"):
            ctx.device.control(line)
    rec = Recorder(out_dir, binding, flush_s=0.05)
    supervisor = assembly.build_supervisor(cfg, binding)
    # the case's budget without a sample is a lost link here (the config's 50 ms is for an unloaded
    # host; STARVATION_BUDGET_S above says why)
    supervisor.limits = dataclasses.replace(supervisor.limits,
                                            link_loss_periods=round(scenario.link_budget_s / assembly.period_s(cfg)),
                                            min_angle_deg=-math.inf, max_angle_deg=math.inf)
    session = open_session(CONFIG, hw=ctx.hw, controller=controller, configure=conf, supervisor=supervisor,
                           sinks=(rec,), realtime=False, sample_timeout_s=SAMPLE_TIMEOUT_S)
    caplog.set_level(logging.ERROR, logger="rehab_hil.supervisor")
    try:
        # the shared device: streaming off (no backlog while we set up), faults of earlier tests cleared
        ctx.hw.configure(dataclasses.replace(conf, sample_rate_hz=0))
        assert ctx.hw.clear(timeout=STARVATION_BUDGET_S), "faults left latched by an earlier test would not clear"
        ctx.hw.discard_pending()
    except Exception as e:
        rec.close()
        session.close()
        raise AssertionError(f"{e}; {ctx.proxy.describe()}; device {ctx.device.control('status')}") from e
    try:
        res = session.run(DURATION_S if scenario.trip is None else TRIP_DURATION_S)
    finally:
        rec.close()
        session.close()
        ctx.settle()
    tap = ctx.proxy.device_tap
    events = [(e.reason, e.detail, round(e.t_s, 3)) for e in res.events]
    host_t = read_csv(rec.csv_path)["host_time_s"]
    worst_gap_ms = float(np.max(np.diff(host_t))) * 1e3 if len(host_t) > 1 else float("nan")
    print(f"\n{scenario.name}: events={events} samples={res.samples} worst_host_gap={worst_gap_ms:.1f} ms "
          f"gaps={res.sample_gaps} link_bad={res.link['bad_frames']} dev_rx_bad={res.link['device_rx_bad_frames']} "
          f"worst_pwm_on_after_cmd={tap.worst_on_since_command_us / 1000:.1f} ms "
          f"pwm_off_after_cmd={[round(t / 1000, 1) for t in tap.pwm_off_after_command_us]} ms "
          f"(across lost samples, last on / first off: {tap.pwm_off_unresolved_us} us); {ctx.proxy.describe()}")
    assert controller.fired_at is not None, "the session ended before the fault was injected"
    return res, rec, conf
