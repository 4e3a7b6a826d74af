"""The real firmware (firmware/rehab_fw) running in simavr: handshake, streaming, PWM registers,
every safety limit, e-stop, bad frames. The host side is the project's SerialHardware over the
harness's pty; the harness drives the encoder/ADC/e-stop pins and reads the PWM registers.

Times are checked in device time (SAMPLE.device_time_us), never against the wall clock."""

from __future__ import annotations

import shutil
import subprocess
from collections.abc import Callable
from itertools import pairwise
from pathlib import Path

import pytest
from cobs import cobs

from rehab_hil.devices.avr_device import adc_counts_to_mv
from rehab_hil.hardware import HardwareError, SerialHardware
from rehab_hil.protocol import (
    DUTY_FULL,
    CommandFrame,
    Configure,
    Fault,
    FaultReport,
    ResetCause,
    Sample,
    Status,
    crc16_ccitt_false,
    encode_frame,
)

from .conftest import HARNESS, ROOT, Hardware, Harness, config

pytestmark = [pytest.mark.firmware, pytest.mark.timeout(60)]

# The PWM resolution: Timer1 fast PWM with TOP = 799 has 800 steps of 12.5 duty units.
PWM_STEP = DUTY_FULL / 800
# ADC input voltages: the avr driver's conversion, checked through simavr's real ADC below.
mv = adc_counts_to_mv


def _next(hw: SerialHardware, timeout: float = 2.0) -> Sample:
    s = hw.read_sample(timeout)
    assert s is not None, f"no SAMPLE within {timeout} s"
    return s


def _until(hw: SerialHardware, pred: Callable[[Sample], bool], max_samples: int = 3000) -> Sample:
    for _ in range(max_samples):
        s = _next(hw)
        if pred(s):
            return s
    raise AssertionError(f"condition not met within {max_samples} samples")


def _applied(hw: SerialHardware, command: CommandFrame) -> Sample:
    seq = hw.send_command(command)
    return _until(hw, lambda s: s.cmd_seq_echo == seq)


def test_handshake_reports_the_uno_capabilities_and_power_on(rig: tuple[Harness, SerialHardware]) -> None:
    _, hw = rig
    info = hw.connect()
    # counts/rev: 0 until a CONFIGURE carries the rig's (the fixture's carries none)
    assert (info.protocol_version, info.n_pwm, info.n_adc, info.encoder_counts_per_rev) == (1, 2, 2, 0)
    assert (info.adc_ref_mv, info.adc_bits, info.max_rate_hz) == (5000, 10, 1000)
    assert info.reset_cause == 1  # power-on, from MCUSR
    assert hw.heartbeat() >= 0


@pytest.mark.parametrize(("rate", "period_us"), [(1000, 1000), (200, 5000), (333, 3000)])
def test_streams_one_sample_per_period_in_device_time(rig: tuple[Harness, SerialHardware], rate: int,
                                                      period_us: int) -> None:
    _, hw = rig
    hw.configure(config(sample_rate_hz=rate))
    hw.discard_pending()
    samples = [_next(hw) for _ in range(30)]
    assert {b.device_time_us - a.device_time_us for a, b in pairwise(samples)} == {period_us}
    assert [s.sample_index for s in samples] == list(range(samples[0].sample_index, samples[0].sample_index + 30))


def test_command_drives_the_timer1_registers_clamped_with_direction_pins(rig: tuple[Harness, SerialHardware]) -> None:
    harness, hw = rig
    hw.configure(config(max_duty=6000))
    s = _applied(hw, CommandFrame(2500, 7000, 0b10, 1))
    assert (s.duty0, s.duty1, s.direction) == (2500, 6000, 0b10)
    assert s.status & Status.DUTY_CLAMPED and s.status & Status.PWM_ENABLED and s.status & Status.WATCHDOG_ARMED
    st = harness.state()  # what the pins do: OCR1A/OCR1B against ICR1, COM bits, PORTB/PORTD
    assert abs(st["duty0"] - 2500) <= PWM_STEP and abs(st["duty1"] - 6000) <= PWM_STEP and st["dir"] == 0b10
    hw.configure(config())
    _applied(hw, CommandFrame(DUTY_FULL, 1, 0b01, 1))
    st = harness.state()
    assert (st["duty0"], st["duty1"], st["dir"]) == (DUTY_FULL, 0, 0b01)  # 100 %: pin high; 1 unit rounds to off
    s = _applied(hw, CommandFrame(5000, 5000, 0b10, 0))
    assert (s.duty0, s.duty1, s.direction) == (0, 0, 0b01) and not s.status & Status.PWM_ENABLED
    assert (harness.state()["duty0"], harness.state()["duty1"]) == (0, 0)


def test_commands_before_configure_are_ignored(harness: Harness) -> None:
    hw = Hardware(harness.port)
    try:
        hw.connect(timeout=10.0)
        hw.send_command(CommandFrame(5000, 5000, 0, 1))
        hw.heartbeat()  # a round trip: the COMMAND before it has been handled
        assert (harness.state()["duty0"], harness.state()["duty1"]) == (0, 0)
        hw.configure(config(sample_rate_hz=100))
        assert _next(hw).cmd_seq_echo == 0
    finally:
        hw.close()


def test_watchdog_cuts_pwm_watchdog_ms_after_the_last_command(rig: tuple[Harness, SerialHardware]) -> None:
    harness, hw = rig
    hw.configure(config(watchdog_ms=25))
    on = _applied(hw, CommandFrame(4000, 0, 0, 1))
    tripped = _until(hw, lambda s: s.faults != 0)
    assert tripped.faults == Fault.WATCHDOG and tripped.duty0 == 0
    # the command arrived within the millisecond before `on`
    assert 24_000 <= tripped.device_time_us - on.device_time_us <= 25_000
    assert harness.state()["duty0"] == 0
    assert FaultReport(Fault.WATCHDOG, Fault.WATCHDOG) in hw.faults_reported, (hw.stats, harness.state())
    ignored = hw.send_command(CommandFrame(4000, 0, 0, 1))
    assert _next(hw).cmd_seq_echo != ignored and harness.state()["duty0"] == 0  # latched until CLEAR
    assert hw.clear()
    assert _applied(hw, CommandFrame(4000, 0, 0, 1)).duty0 == 4000


def test_heating_time_limit(rig: tuple[Harness, SerialHardware]) -> None:
    harness, hw = rig
    hw.configure(config(max_heating_ms=30))
    on = _applied(hw, CommandFrame(100, 0, 0, 1))
    tripped = _until(hw, lambda s: s.faults != 0)
    assert tripped.faults == Fault.HEATING_TIME and harness.state()["duty0"] == 0
    assert 29_000 <= tripped.device_time_us - on.device_time_us <= 30_000
    assert hw.clear()


def test_force_limit_trips_and_clear_waits_for_the_force_to_drop(rig: tuple[Harness, SerialHardware]) -> None:
    harness, hw = rig
    harness.send(f"A 0 {mv(500)}")
    hw.configure(config(force_limit_counts=600))
    assert _applied(hw, CommandFrame(3000, 3000, 0, 1)).adc0 == 500
    harness.send(f"A 0 {mv(601)}")
    s = _until(hw, lambda s: s.faults != 0)
    assert s.faults == Fault.FORCE_LIMIT and s.adc0 == 601 and (s.duty0, s.duty1) == (0, 0)
    assert (harness.state()["duty0"], harness.state()["duty1"]) == (0, 0)
    assert not hw.clear()  # cause present
    harness.send(f"A 0 {mv(600)}")  # at the limit is allowed
    _until(hw, lambda s: s.adc0 == 600)
    assert hw.clear()
    hw.discard_pending()  # samples sent before the ACK
    assert _next(hw).faults == 0


@pytest.mark.parametrize("counts", [0, 1, 2, 511, 512, 777, 1022, 1023])
def test_adc_counts_through_simavr_match_the_driver_conversion(rig: tuple[Harness, SerialHardware],
                                                                counts: int) -> None:
    harness, hw = rig
    harness.send(f"A 0 {mv(counts)}")
    harness.send(f"A 1 {mv(1023 - counts)}")
    s = _until(hw, lambda s: (s.adc0, s.adc1) == (counts, 1023 - counts), max_samples=50)
    assert s.faults == 0


def test_range_of_motion_from_encoder_edges(rig: tuple[Harness, SerialHardware]) -> None:
    harness, hw = rig
    hw.configure(config(enc_min=-50, enc_max=300))
    harness.send("E 300")  # 300 quadrature edges on D2/D3
    s = _until(hw, lambda s: s.encoder_count == 300)
    assert s.faults == 0
    _applied(hw, CommandFrame(2000, 0, 0, 1))
    harness.send("E 301")
    s = _until(hw, lambda s: s.faults != 0)
    assert s.faults == Fault.RANGE_OF_MOTION and s.encoder_count == 301 and s.duty0 == 0
    assert not hw.clear()
    harness.send("E -51")  # backwards through the range, out at the other end
    s = _until(hw, lambda s: s.encoder_count == -51)
    assert s.faults == Fault.RANGE_OF_MOTION
    harness.send("E 0")
    _until(hw, lambda s: s.encoder_count == 0)
    assert hw.clear()


def test_estop_input_pin(rig: tuple[Harness, SerialHardware]) -> None:
    harness, hw = rig
    # disabled: the pin shows in the status but does not trip
    harness.send("D 4 0")
    s = _until(hw, lambda s: bool(s.status & Status.ESTOP_INPUT_ACTIVE))
    assert s.faults == 0
    harness.send("D 4 1")
    _until(hw, lambda s: not s.status & Status.ESTOP_INPUT_ACTIVE)
    hw.configure(config(flags=Configure.FLAG_ESTOP_INPUT))
    _applied(hw, CommandFrame(3000, 0, 0, 1))
    harness.send("D 4 0")
    s = _until(hw, lambda s: s.faults != 0)
    assert s.faults == Fault.ESTOP_INPUT and s.duty0 == 0 and harness.state()["duty0"] == 0
    assert not hw.clear()
    harness.send("D 4 1")
    _until(hw, lambda s: not s.status & Status.ESTOP_INPUT_ACTIVE)
    assert hw.clear()


def test_a_normally_closed_estop_loop_trips_when_opened_by_the_button_or_a_broken_wire(
        rig: tuple[Harness, SerialHardware]) -> None:
    harness, hw = rig
    harness.send("D 4 0")  # the NC loop intact holds D4 low: released
    hw.configure(config(flags=Configure.FLAG_ESTOP_INPUT | Configure.FLAG_ESTOP_NORMALLY_CLOSED))
    s = _applied(hw, CommandFrame(3000, 0, 0, 1))
    assert s.faults == 0 and not s.status & Status.ESTOP_INPUT_ACTIVE and s.duty0 > 0
    harness.send("D 4 1")  # loop opened (pressed, or the wire cut): the pull-up reads high
    s = _until(hw, lambda s: s.faults != 0)
    assert s.faults == Fault.ESTOP_INPUT and s.status & Status.ESTOP_INPUT_ACTIVE and harness.state()["duty0"] == 0
    assert not hw.clear()
    harness.send("D 4 0")
    _until(hw, lambda s: not s.status & Status.ESTOP_INPUT_ACTIVE)
    assert hw.clear()
    harness.send("D 4 1")  # leave the pin pulled up for the next test


def test_force_limit_is_debounced_noise_bursts_pass_a_real_overload_trips(
        rig: tuple[Harness, SerialHardware]) -> None:
    harness, hw = rig
    harness.send(f"A 0 {mv(500)}")
    hw.configure(config(force_limit_counts=600, force_debounce_ms=3))
    assert _applied(hw, CommandFrame(3000, 0, 0, 1)).adc0 == 500
    for _ in range(5):  # 1.5 ms bursts: above the limit for at most 2 ticks, never 3 in a row
        harness.send(f"P 0 {mv(900)} 1500")
        _until(hw, lambda s: s.adc0 == 900, max_samples=50)  # one burst at a time, each seen
        _until(hw, lambda s: s.adc0 == 500, max_samples=50)
    for _ in range(20):
        s = _next(hw)
    assert s.faults == 0 and s.duty0 > 0
    harness.send(f"A 0 {mv(900)}")  # a real overload
    s = _until(hw, lambda s: s.faults != 0)
    assert s.faults == Fault.FORCE_LIMIT and harness.state()["duty0"] == 0
    harness.send(f"A 0 {mv(500)}")
    _until(hw, lambda s: s.adc0 == 500)
    assert hw.clear()


def test_estop_command_latches_until_clear(rig: tuple[Harness, SerialHardware]) -> None:
    harness, hw = rig
    on = _applied(hw, CommandFrame(3000, 2000, 0, 1))
    hw.estop()
    assert harness.state()["duty0"] == 0 and harness.state()["duty1"] == 0  # off before the ACK came back
    hw.send_command(CommandFrame(3000, 0, 0, 1))
    s = _until(hw, lambda s: s.faults != 0)
    s = _next(hw)
    assert s.faults == Fault.ESTOP_COMMAND and s.cmd_seq_echo == on.cmd_seq_echo and s.duty0 == 0
    assert FaultReport(Fault.ESTOP_COMMAND, Fault.ESTOP_COMMAND) in hw.faults_reported
    assert hw.clear()
    assert _applied(hw, CommandFrame(3000, 0, 0, 1)).faults == 0


def test_bad_configuration_is_refused_and_latched(rig: tuple[Harness, SerialHardware]) -> None:
    _, hw = rig
    for bad in (config(watchdog_ms=0), config(max_duty=DUTY_FULL + 1), config(max_heating_ms=0),
                config(force_limit_counts=1024), config(enc_min=10, enc_max=10)):
        with pytest.raises(HardwareError, match="result 2"):
            hw.configure(bad)
        hw.discard_pending()
        assert _next(hw).faults == Fault.BAD_CONFIG
        assert hw.clear()


def _packet(version: int, mtype: int, payload: bytes, seq: int = 1) -> bytes:
    body = bytes([version, mtype, seq & 0xFF, seq >> 8]) + payload
    crc = crc16_ccitt_false(body)
    return body + bytes([crc & 0xFF, crc >> 8])


def test_corrupt_frames_are_counted_and_dropped(rig: tuple[Harness, SerialHardware]) -> None:
    _, hw = rig
    before = _next(hw)
    good = encode_frame(CommandFrame(3000, 0, 0, 1), 900)
    bad = [
        b"\x01\x02\x03\x00",  # short
        good[:6] + b"\x00",  # truncated
        b"\x05\x01\x02\x00",  # cobs: code byte past the end
        cobs.encode(_packet(1, 0x03, bytes(6))[:-1] + b"\x01") + b"\x00",  # crc
        cobs.encode(_packet(9, 0x03, bytes(6))) + b"\x00",  # version
        cobs.encode(_packet(1, 0x42, b"")) + b"\x00",  # unknown type
        cobs.encode(_packet(1, 0x82, bytes(29))) + b"\x00",  # a device->host type
        cobs.encode(_packet(1, 0x03, bytes(4))) + b"\x00",  # length
        b"\x07" * 200 + b"\x00",  # overflow, counted once
    ]
    hw.send_raw(b"\x00\x00" + b"".join(bad))  # empty frames are not counted
    hw.send_raw(good)
    s = _until(hw, lambda s: s.cmd_seq_echo == 900 or s.rx_bad_frames - before.rx_bad_frames > len(bad),
               max_samples=200)
    assert s.rx_bad_frames - before.rx_bad_frames == len(bad)
    assert s.duty0 == 3000


def test_external_reset_reboots_unconfigured_with_a_hello(rig: tuple[Harness, SerialHardware]) -> None:
    harness, hw = rig
    _applied(hw, CommandFrame(3000, 0, 0, 1))
    harness.send("R")
    # the reboot shows as an unsolicited HELLO with seq 0; SerialHardware counts it
    hello = hw.connect(timeout=10.0)
    assert hw.stats.reboots == 1 and hello.reset_cause == ResetCause.EXTERNAL
    assert (harness.state()["duty0"], harness.state()["resets"]) == (0, 1)
    hw.send_command(CommandFrame(3000, 0, 0, 1))  # unconfigured: ignored
    hw.heartbeat()
    assert harness.state()["duty0"] == 0


def test_a_flood_of_commands_is_survived_and_the_link_recovers(rig: tuple[Harness, SerialHardware]) -> None:
    """300 COMMANDs back to back saturate the 1 Mbaud link (100 kB/s); the firmware may drop some
    (counted, see firmware/README.md) but must not reset or hang, and must apply the next one."""
    harness, hw = rig
    before = _next(hw)
    hw.send_raw(b"".join(encode_frame(CommandFrame(1000 + i, 0, 0, 1), 2000 + i) for i in range(300)))
    # let the flood drain (42 ms on the wire): the echo enters the flood, then stops moving
    s = _until(hw, lambda s: s.cmd_seq_echo >= 2000)
    stable, echo = 0, s.cmd_seq_echo
    while stable < 60:
        s = _next(hw)
        stable, echo = (stable + 1, echo) if s.cmd_seq_echo == echo else (0, s.cmd_seq_echo)
    assert 2000 <= s.cmd_seq_echo < 2300 and s.duty0 == s.cmd_seq_echo - 1000  # flood frames were applied
    # A dropped byte may have been the last flood frame's delimiter, leaving the receiver mid-frame:
    # a lone 0x00 resynchronises it (docs/protocol.md) before the next frame.
    hw.send_raw(b"\x00")
    s = _applied(hw, CommandFrame(4321, 0, 0, 1))
    assert s.duty0 == 4321 and s.faults == 0
    assert harness.state()["resets"] == 0
    dropped = s.rx_bad_frames - before.rx_bad_frames
    assert 0 <= dropped < 300


def test_a_build_pinned_to_one_encoder_reports_it_and_refuses_another(tmp_path: Path) -> None:
    """`make ENCODER_COUNTS_PER_REV=2000` (the default build adopts CONFIGURE's value instead)."""
    if shutil.which("avr-gcc") is None or not HARNESS.exists():
        pytest.skip("no avr-gcc or harness: run `make firmware harness`")
    subprocess.run(["make", "-s", "-C", str(ROOT / "firmware"), "ENCODER_COUNTS_PER_REV=2000"], check=True,
                   capture_output=True, timeout=300)
    h = Harness(ROOT / "firmware" / "build" / "cpr2000" / "rehab_fw.elf")
    hw = Hardware(h.port)
    try:
        assert hw.connect(timeout=10.0).encoder_counts_per_rev == 2000  # from boot
        hw.configure(config(encoder_counts_per_rev=2000))
        with pytest.raises(HardwareError, match=r"ACK result 2.*reports 2000 encoder counts/rev, the config 4096"):
            hw.configure(config(encoder_counts_per_rev=4096))
        assert hw.connect().encoder_counts_per_rev == 2000
    finally:
        hw.close()
        h.close()
