"""``rehab-hil doctor --config C --device D``: self-test a rig with the PWM locked off.

Never commands a duty > 0: it sends no COMMAND at all, and after checking that the firmware
accepts the session's limits it re-configures with ``max_duty = 0`` so the firmware itself clamps
anything to 0. Checks: handshake and versions, the limits the firmware accepted, sample rate and
link quality, PWM off in every sample, the e-stop loop (status bit, read-only), latched faults, the
force sensor at rest, the encoder moving when the user moves the finger, the force sensor under a
press. Prints a pass/fail table; exit status 0 when nothing failed, 1 otherwise.

With ``--yes`` nothing waits for Enter; each manual step waits at most ``--timeout`` seconds. On
the simulated devices (``sim``, ``avr``) ``--yes`` also plays the user: it moves the plant through
the device's control channel (``input NAME VALUE``, docs/protocol.md) where the plant has a
patient input that moves the finger or loads the sensor, and skips the step otherwise.
"""

from __future__ import annotations

import argparse
import dataclasses
import statistics
import time
from collections.abc import Callable, Iterator
from contextlib import ExitStack, contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from rich.console import Console
from rich.table import Table

from rehab_hil.cli import UserError, config_file, device_arg
from rehab_hil.hardware import HardwareError, HardwareInterface
from rehab_hil.protocol import BASE_RATE_HZ, PROTOCOL_VERSION, Configure, Fault, Sample, Status

__all__ = ["Check", "Hand", "SimulatedHand", "collect", "locked_configure", "open_for_checks", "run_checks"]

# Simulated user: plant inputs that move the finger (encoder) or load A0, and the value applied.
SIM_MOVE_INPUTS = {"patient_torque_nm": 1.0, "measured_force_n": 3.0}
SIM_PRESS_INPUTS = {"patient_torque_nm": 1.0}  # the Finger Extensor's A0 reads this input
RAIL_COUNTS = 2  # A0 within this of 0 or 1023: railed (open circuit, short, saturated amplifier)
MAX_REST_NOISE_COUNTS = 5.0
PRESS_RISE_COUNTS = 20  # a press must lift A0 this far above rest


@dataclass(frozen=True)
class Check:
    """One row of the table: ``status`` is PASS, FAIL, WARN or SKIP."""

    name: str
    status: str
    detail: str


class Hand:
    """The user at the bench: ``act`` asks for an action (and waits for Enter when interactive),
    ``release`` ends it. Returns False from ``act`` when the action cannot be done (then SKIP)."""

    def __init__(self, interactive: bool, say: Callable[[str], Any] = print) -> None:
        self.interactive, self.say = interactive, say

    def act(self, step: str, instruction: str) -> bool:
        self.say(f"doctor: {instruction}")
        if self.interactive:
            input("press Enter, then do it ... ")
        return True

    def release(self, step: str) -> None:
        if self.interactive:
            self.say("doctor: thank you, let go")

    def load(self, channel: int, value: float) -> bool:
        """Put a known load on ADC ``channel``'s sensor (its unit); False: a person places it."""
        return False


class SimulatedHand(Hand):
    """Plays the user on a simulated device through its control channel (``input NAME VALUE``)."""

    def __init__(self, device: Any, constant_inputs: dict[str, float], say: Callable[[str], Any] = print) -> None:
        super().__init__(False, say)
        self.device, self.inputs = device, constant_inputs

    def _knobs(self, step: str) -> dict[str, float]:
        table = SIM_MOVE_INPUTS if step == "move" else SIM_PRESS_INPUTS
        return {k: v for k, v in table.items() if k in self.inputs}

    def act(self, step: str, instruction: str) -> bool:
        knobs = self._knobs(step)
        if not knobs:
            return False
        for name, value in knobs.items():
            self.say(f"doctor: simulated user: input {name} {value}")
            self.device.control(f"input {name} {value}")
        return True

    def release(self, step: str) -> None:
        for name in self._knobs(step):
            self.device.control(f"input {name} {self.inputs[name]}")

    def load(self, channel: int, value: float) -> bool:
        """The simulated sensor carries ``value`` (control ``load CHANNEL VALUE``)."""
        self.device.control(f"load {channel} {value:.9g}")
        return True


def locked_configure(msg: Configure) -> Configure:
    """The same CONFIGURE with ``max_duty = 0``: the firmware clamps every COMMAND to 0."""
    return dataclasses.replace(msg, max_duty=0)


def collect(hw: HardwareInterface, seconds: float, until: Callable[[Sample], bool] | None = None) -> list[Sample]:
    """Samples for ``seconds`` (or until ``until(sample)`` is true; that sample is the last)."""
    out: list[Sample] = []
    deadline = time.perf_counter() + seconds
    while (left := deadline - time.perf_counter()) > 0:
        s = hw.read_sample(timeout=min(left, 0.2))
        if s is None:
            continue
        out.append(s)
        if until is not None and until(s):
            break
    return out


def _fault_names(bits: int) -> str:
    names = [n for n in dir(Fault) if n.isupper() and isinstance(getattr(Fault, n), int) and bits & getattr(Fault, n)]
    return ", ".join(sorted(names)) or "none"


def run_checks(hw: HardwareInterface, cfg: Any, binding: Any, hand: Hand, *, seconds: float = 2.0,
               timeout_s: float = 15.0, expected_fw: tuple[int, int, int] | None = None) -> list[Check]:
    """Every check on a connected rig (``hw`` INACTIVE, HELLO known); never sends a COMMAND."""
    info = hw.info
    assert info is not None
    rows = _handshake_rows(info, binding, expected_fw)
    limits, real = _try_limits(hw, cfg, binding)
    rows.append(limits)
    stale, rest, link = _listen_locked(hw, cfg, real or firmware_configure_fallback(cfg, binding), seconds)
    rows.append(link)
    if not rest:
        return [*rows, Check("sensors", "FAIL", "no samples: nothing else can be checked")]
    rows += _at_rest_rows(rest, stale)
    a0 = _ForceSensor.of(cfg, binding)
    row, mean0 = a0.rest_row(rest)
    rows.append(row)
    rows.append(_manual(hw, hand, "move", "encoder moves",
                        "move the finger (or back-drive the actuator by hand) through part of its range",
                        lambda s: abs(s.encoder_count - rest[-1].encoder_count) >= _motion_counts(binding),
                        lambda s: _moved(s.encoder_count - rest[-1].encoder_count, binding.encoder_counts_per_rev),
                        "did not move (check A/B wiring, pull-ups, 5 V to the encoder)", timeout_s))
    rows.append(_manual(hw, hand, "press", f"{a0.label} under a press", "press the force sensor firmly with a finger",
                        lambda s: s.adc0 - mean0 >= PRESS_RISE_COUNTS,
                        lambda s: f"rose {s.adc0 - mean0:+.0f} counts to {s.adc0} = {a0.in_units(s.adc0)}",
                        f"did not rise {PRESS_RISE_COUNTS} counts above rest (sensor, gain R_f or wiring)", timeout_s))
    return rows


def _handshake_rows(info: Any, binding: Any, expected_fw: tuple[int, int, int] | None) -> list[Check]:
    """The protocol and firmware versions the HELLO reported, and a counts/rev that disagrees with the config."""
    fw = (info.fw_major, info.fw_minor, info.fw_patch)
    fw_ok = info.protocol_version == PROTOCOL_VERSION and (expected_fw is None or fw == expected_fw)
    rows = [Check("handshake", "PASS" if fw_ok else "FAIL",
                  f"protocol v{info.protocol_version} (host v{PROTOCOL_VERSION}), firmware "
                  f"{'.'.join(map(str, fw))}" + (f" (expected {'.'.join(map(str, expected_fw))})" if expected_fw
                                                 else "") + f", reset cause {info.reset_cause:#x}")]
    # 0: the device has not been told yet (it adopts CONFIGURE's counts/rev, protocol.md)
    if binding.encoder_counts_per_rev and info.encoder_counts_per_rev not in (0, binding.encoder_counts_per_rev):
        rows.append(Check("encoder counts/rev", "WARN", f"device reports {info.encoder_counts_per_rev}, config "
                          f"{binding.encoder_counts_per_rev}: angles will be scaled wrongly"))
    return rows


def _try_limits(hw: HardwareInterface, cfg: Any, binding: Any) -> tuple[Check, Configure | None]:
    """Send the session's real CONFIGURE: does the firmware accept its limits? Returns the row and the
    CONFIGURE (None when the config's limits cannot be built)."""
    from rehab_hil.calibration import ForceLimitError
    from rehab_hil.service.assembly import firmware_configure

    try:
        real = firmware_configure(cfg, binding)
    except ForceLimitError as e:
        return Check("limits accepted", "FAIL", str(e)), None
    try:
        hw.configure(real)
    except HardwareError as e:
        return Check("limits accepted", "FAIL", str(e)), real
    return Check("limits accepted", "PASS",
                 f"rate {real.sample_rate_hz} Hz, watchdog {real.watchdog_ms} ms, max duty "
                 f"{real.max_duty / 100:.0f} %, heating {real.max_heating_ms} ms, force limit "
                 f"{real.force_limit_counts} counts{' (off)' if real.force_limit_counts >= 1023 else ''}, "
                 f"encoder {real.enc_min}..{real.enc_max}"), real


def _listen_locked(hw: HardwareInterface, cfg: Any, base: Configure, seconds: float) -> tuple[int, list[Sample], Check]:
    """Lock the PWM (``base`` with max_duty 0), clear stale faults, time a heartbeat and collect
    ``seconds`` of samples at rest: (the faults found latched, the samples, the link's row)."""
    hw.configure(locked_configure(base))  # from here the firmware clamps every duty to 0
    first = hw.read_sample(timeout=1.0)
    stale = first.faults if first is not None else 0
    if stale:  # e.g. WATCHDOG from an earlier session; CLEAR keeps those whose cause holds
        hw.clear()
    hw.discard_pending()
    t0 = time.perf_counter()
    try:
        hw.heartbeat(timeout=1.0)
        rtt_ms = 1000 * (time.perf_counter() - t0)
    except HardwareError:
        rtt_ms = float("nan")
    hw.discard_pending()
    bad0 = sum(hw.stats.bad_frames.values())
    rest = collect(hw, seconds)
    return stale, rest, _link_row(rest, cfg, rtt_ms, sum(hw.stats.bad_frames.values()) - bad0)


def _at_rest_rows(rest: list[Sample], stale: int) -> list[Check]:
    """PWM off in every sample, the e-stop loop closed, no fault latched at the end."""
    pwm_on = [s for s in rest if s.duty0 or s.duty1 or s.status & Status.PWM_ENABLED]
    estop = [s for s in rest if s.status & Status.ESTOP_INPUT_ACTIVE]
    faults = rest[-1].faults
    cleared = stale & ~faults
    return [
        Check("PWM off", "FAIL" if pwm_on else "PASS",
              f"{len(pwm_on)} of {len(rest)} samples with PWM on" if pwm_on
              else f"duty 0 in all {len(rest)} samples (max_duty 0 configured)"),
        Check("e-stop loop", "FAIL" if estop else "PASS",
              "e-stop input active: button pressed or loop open (check the NC loop, docs/wiring.md)"
              if estop else "closed (e-stop input inactive)"),
        Check("faults at rest", "FAIL" if faults else "PASS", _fault_names(faults)
              + (f" (cleared at start: {_fault_names(cleared)})" if cleared else "")),
    ]


@dataclass(frozen=True)
class _ForceSensor:
    """The sensor on A0 as the checks read it: its calibration (``calibration_for``) or the config's
    ADC channel, either of which may be missing."""

    cal: Any
    channel: Any

    @classmethod
    def of(cls, cfg: Any, binding: Any) -> _ForceSensor:
        from rehab_hil.calibration import calibration_for

        return cls(calibration_for(cfg), binding.adc[0] if binding.adc else None)

    @property
    def label(self) -> str:
        return f"A0 ({self.channel.signal})" if self.channel else "A0"

    def in_units(self, counts: float) -> str:
        if self.cal is not None:
            return f"{float(self.cal.force_n(counts)):.2f} N"
        if self.channel is not None:
            return f"{(counts - self.channel.offset_counts) / self.channel.counts_per_unit:.3g} {self.channel.unit}"
        return ""

    def rest_row(self, rest: list[Sample]) -> tuple[Check, float]:
        """A0 at rest: railed, noisy or fine; returns the row and the rest level (counts)."""
        a0 = [s.adc0 for s in rest]
        mean0, sd0 = statistics.fmean(a0), statistics.pstdev(a0)
        ch, cal = self.channel, self.cal
        rest_expected = cal.data.tare_counts if cal is not None else (ch.offset_counts if ch is not None else 0.0)
        low_rail_is_fault = rest_expected > 5 * RAIL_COUNTS  # an op-amp Flexiforce reads ~0 unloaded: normal
        name = f"{self.label} at rest"
        if max(a0) >= 1023 - RAIL_COUNTS or (low_rail_is_fault and min(a0) <= RAIL_COUNTS):
            return Check(name, "FAIL", f"railed at {mean0:.0f} counts (open circuit, short or a saturated "
                         "amplifier; check the op-amp circuit, docs/wiring.md)"), mean0
        if sd0 > MAX_REST_NOISE_COUNTS:
            return Check(name, "FAIL", f"noisy: {mean0:.1f} +- {sd0:.1f} counts (loose wire? the ADC needs a "
                         "low-impedance source)"), mean0
        return Check(name, "PASS", f"{mean0:.1f} +- {sd0:.2f} counts = {self.in_units(mean0)}"), mean0


def firmware_configure_fallback(cfg: Any, binding: Any) -> Configure:
    """A CONFIGURE with the force limit off, for the sensor checks when the real one cannot be built."""
    from rehab_hil.hardware.interface import configure_from_config

    return configure_from_config(cfg, binding.encoder_counts_per_rev, force_limit_counts=1023)


def _moved(counts: int, per_rev: int) -> str:
    return f"moved {counts:+d} counts ({360.0 * counts / max(per_rev, 1):+.1f} deg)"


def _motion_counts(binding: Any) -> int:
    """Encoder motion that counts as moved: 2 degrees, at least 4 counts."""
    return max(4, round(binding.encoder_counts_per_rev * 2.0 / 360.0))


def _manual(hw: HardwareInterface, hand: Hand, step: str, name: str, instruction: str,
            done: Callable[[Sample], bool], passed: Callable[[Sample], str], failed: str, timeout_s: float) -> Check:
    hw.discard_pending()
    if not hand.act(step, f"{instruction} (within {timeout_s:g} s)"):
        return Check(name, "SKIP", "simulated device: no patient input that does this (manual on a real rig)")
    try:
        got = collect(hw, timeout_s, until=done)
    finally:
        hand.release(step)
    if got and done(got[-1]):
        return Check(name, "PASS", passed(got[-1]))
    return Check(name, "FAIL", f"{failed} within {timeout_s:g} s")


def _link_row(samples: list[Sample], cfg: Any, rtt_ms: float, host_bad: int) -> Check:
    rate = cfg.rig.sample_rate_hz
    k = max(1, int((BASE_RATE_HZ + rate // 2) // rate))
    expected = BASE_RATE_HZ / k
    if len(samples) < 2:
        return Check("sample rate / link", "FAIL", f"{len(samples)} samples received")
    first, last = samples[0], samples[-1]
    sent = (last.sample_index - first.sample_index) & 0xFFFFFFFF
    span_s = ((last.device_time_us - first.device_time_us) & 0xFFFFFFFF) / 1e6
    dev_rate = sent / span_s if span_s > 0 else 0.0
    lost = sent + 1 - len(samples)
    loss_pct = 100.0 * lost / (sent + 1)
    device_bad = (last.rx_bad_frames - first.rx_bad_frames) & 0xFFFF
    ok = abs(dev_rate - expected) <= 0.02 * expected and loss_pct <= 1.0 and host_bad == 0 and device_bad == 0
    return Check("sample rate / link", "PASS" if ok else "FAIL",
                 f"{dev_rate:.0f} Hz device time (expected {expected:.0f}), {len(samples)} received, {lost} lost "
                 f"({loss_pct:.2f} %), bad frames host {host_bad} / device {device_bad}, heartbeat {rtt_ms:.1f} ms")


def table(rows: list[Check], title: str) -> Table:
    t = Table(title=title)
    for col in ("check", "result", "detail"):
        t.add_column(col)
    colour = {"PASS": "green", "FAIL": "red", "WARN": "yellow", "SKIP": "dim"}
    for r in rows:
        t.add_row(r.name, f"[{colour[r.status]}]{r.status}", r.detail)
    return t


@contextmanager
def open_for_checks(device: str, config_path: Path, cfg: Any, binding: Any, interactive: bool,
                    say: Callable[[str], Any]) -> Iterator[tuple[HardwareInterface, Hand]]:
    """Open the rig (connected, not configured) and the hand that plays or asks the user. Simulated
    devices are spawned here so that ``--yes`` can move their plant (``SimulatedHand``)."""
    from rehab_hil.hardware import SerialHardware, open_rig
    from rehab_hil.hardware.discovery import announce_device

    with ExitStack() as stack:
        if device in ("sim", "avr"):
            from rehab_hil.devices import spawn_device

            announce_device(device, config_path, cfg.rig.port)
            try:
                dev = stack.enter_context(spawn_device(device, config_path, clock="realtime"))
            except Exception as e:  # DeviceProcessError, a missing simavr build ...
                raise UserError(f"--device {device}: {e}") from None
            hw: HardwareInterface = SerialHardware(dev.port, cfg.rig.baud, write_timeout_s=1.0)
            stack.callback(hw.close)
            hw.connect(timeout=10.0)
            hand: Hand = Hand(True, say) if interactive else SimulatedHand(dev, dict(binding.constant_inputs), say)
        elif device == "inprocess":
            raise UserError("--device inprocess is lockstep (no sample stream without commands); use sim or avr")
        else:
            hw = stack.enter_context(open_rig(device, config_path, baud=cfg.rig.baud))
            hand = Hand(interactive, say)
        yield hw, hand


def add_parser(sub: argparse._SubParsersAction) -> argparse.ArgumentParser:
    p = sub.add_parser("doctor", help="self-test a rig with PWM locked off: link, limits, e-stop, encoder, force")
    p.add_argument("--config", required=True, type=config_file, help="plant config (configs/*.toml)")
    p.add_argument("--device", default=None, type=device_arg,
                   help="sim, avr, auto or a serial path (default: [rig].port)")
    p.add_argument("--seconds", type=float, default=3.0, help="how long to measure the link at rest [s]")
    p.add_argument("--timeout", type=float, default=15.0, help="how long each manual step may take [s]")
    p.add_argument("--yes", action="store_true", help="non-interactive: no Enter; simulated devices play the user")
    return p


def run(args: argparse.Namespace) -> int:
    from rehab_hil.cli.flash import expected_firmware_version
    from rehab_hil.loading import load_config
    from rehab_hil.plants import get_plant

    cfg = load_config(args.config)
    if not 0 < args.seconds <= 600 or not 0 < args.timeout <= 600:
        raise UserError("--seconds and --timeout must be in (0, 600] s")
    binding = get_plant(cfg.plant).device(cfg)
    device = args.device or cfg.rig.port
    console = Console()
    with ExitStack() as stack:
        try:
            hw, hand = stack.enter_context(open_for_checks(device, args.config, cfg, binding, not args.yes,
                                                           console.print))
            rows = run_checks(hw, cfg, binding, hand, seconds=args.seconds, timeout_s=args.timeout,
                              expected_fw=expected_firmware_version())
        except HardwareError as e:
            raise UserError(f"--device {device}: {e}") from None
    failed = [r for r in rows if r.status == "FAIL"]
    console.print(table(rows, f"rehab-hil doctor: {args.config} on {device}: "
                              + ("PASS" if not failed else f"{len(failed)} FAILED")))
    return 1 if failed else 0
