"""One conformance suite for every device backend (docs/protocol.md, "Behaviour"): the Python
simulated device and the firmware in simavr must behave the same on the wire.

Times are checked in device time (SAMPLE.device_time_us), never against the wall clock. A device
is shared by the tests of this module, so each test configures it afresh, clears faults and sets
its limits relative to the plant's current position.
"""

from __future__ import annotations

import itertools
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from typing import Any

import pytest

from rehab_hil.hardware import HardwareError, SerialHardware
from rehab_hil.protocol import (
    DUTY_FULL,
    PROTOCOL_VERSION,
    CommandFrame,
    Configure,
    Fault,
    FaultReport,
    Sample,
    Status,
    crc16_ccitt_false,
    encode_frame,
)

from .conftest import avr_skip_reason

pytestmark = [pytest.mark.slow, pytest.mark.timeout(180), pytest.mark.xdist_group("sim_devices")]

WIDE = 1 << 30


NC = Configure.FLAG_ESTOP_NORMALLY_CLOSED  # the simulated rigs are wired as configs/*.toml say: a closed loop


def _config(**kw: int) -> Configure:
    base = dict(sample_rate_hz=1000, watchdog_ms=200, max_duty=DUTY_FULL, max_heating_ms=60_000,
                force_limit_counts=1023, enc_min=-WIDE, enc_max=WIDE, flags=NC)
    base.update(kw)
    return Configure(**base)


@pytest.fixture(params=["python", "avr"])
def backend(request: pytest.FixtureRequest) -> str:
    if request.param == "avr":
        reason = avr_skip_reason()
        if reason:
            pytest.skip(reason)
    return request.param


def _reset(hw: SerialHardware) -> SerialHardware:
    """Drop the backlog, configure wide open and clear whatever an earlier test left latched."""
    hw.flush_input()
    hw.configure(_config(), timeout=15.0)
    assert hw.clear(timeout=15.0), "faults left over from another test would not clear"
    hw.discard_pending()
    return hw


def _quiet(hw: SerialHardware) -> None:
    """Stop streaming between tests so no backlog piles up in the pty."""
    hw.configure(_config(sample_rate_hz=0), timeout=15.0)


@pytest.fixture
def rig(backend: str, device_pool: Callable[..., Any]) -> Iterator[tuple[Any, SerialHardware]]:
    """A real-time device, connected, configured wide open, faults cleared."""
    device, hw = device_pool(backend, "realtime")
    yield device, _reset(hw)
    _quiet(hw)


@pytest.fixture
def lockstep_rig(backend: str, device_pool: Callable[..., Any]) -> Iterator[tuple[Any, SerialHardware]]:
    """A lockstep device (one SAMPLE per COMMAND), connected, configured wide open."""
    try:
        device, hw = device_pool(backend, "lockstep")
    except ValueError as e:  # a backend without a lockstep clock
        pytest.skip(str(e))
    yield device, _reset(hw)
    _quiet(hw)


def _next(hw: SerialHardware, timeout: float = 10.0) -> Sample:  # lockstep: generous on a busy machine
    s = hw.read_sample(timeout)
    assert s is not None, f"no SAMPLE within {timeout} s"
    return s


def _until(hw: SerialHardware, pred: Callable[[Sample], bool], max_samples: int = 5000) -> Sample:
    for _ in range(max_samples):
        s = _next(hw)
        if pred(s):
            return s
    raise AssertionError(f"condition not met within {max_samples} samples")


def _fresh(hw: SerialHardware) -> Sample:
    """Discard queued samples; the next one was sent after the last acknowledged request."""
    hw.discard_pending()
    return _next(hw)


def _step(hw: SerialHardware, command: CommandFrame) -> tuple[int, Sample]:
    """Lockstep: one COMMAND and the SAMPLE that answers it, the first that echoes it or shows a
    latched fault (the device then ignores commands). The Python device applies a COMMAND before its
    sample; the firmware streams on its own timer and applies one that lands late in a tick at the
    next, so its sample may not echo it yet: the host then sends it again, as its loop would."""
    hw.discard_pending()  # the firmware streamed while a request was pending: samples from before
    for _ in range(10):
        seq = hw.send_command(command)
        s = _next(hw)
        if s.cmd_seq_echo == seq or s.status & Status.FAULT_LATCHED:
            return seq, s
    raise AssertionError(f"{command} was not applied in ten sample periods (last: {s})")


@dataclass
class Stepped:
    """A device driven command by command, whatever its clock."""

    device: Any
    hw: SerialHardware
    lockstep: bool

    def step(self, command: CommandFrame) -> tuple[int, Sample]:
        """Send a COMMAND; return its seq and the first SAMPLE taken after the device handled it
        (lockstep: the COMMAND's own sample; real time: the first sample after a HEARTBEAT round
        trip, since the device handles frames in order)."""
        if self.lockstep:
            return _step(self.hw, command)
        seq = self.hw.send_command(command)
        self.hw.heartbeat(timeout=5.0)
        self.hw.discard_pending()
        return seq, _next(self.hw)


@pytest.fixture
def stepped(backend: str, device_pool: Callable[..., Any]) -> Iterator[Stepped]:
    """Both backends on their lockstep clock (virtual time): the same result on any machine load."""
    device, hw = device_pool(backend, "lockstep")
    yield Stepped(device, _reset(hw), True)
    _quiet(hw)


def test_handshake_reports_capabilities(rig: tuple[Any, SerialHardware]) -> None:
    _, hw = rig
    info = hw.connect()
    assert (info.protocol_version, info.n_pwm, info.n_adc) == (PROTOCOL_VERSION, 2, 2)
    assert (info.adc_ref_mv, info.adc_bits, info.max_rate_hz) == (5000, 10, 1000)
    assert hw.heartbeat() > 0


def test_configure_carries_the_encoder_resolution_which_the_device_adopts_and_reports(
        rig: tuple[Any, SerialHardware]) -> None:
    """The encoder is the rig's: the device takes CONFIGURE's counts/rev (0 keeps it) and says it in
    HELLO; 1..3 counts/rev is no encoder and refused."""
    _, hw = rig
    hw.configure(_config(encoder_counts_per_rev=4096))
    assert hw.connect().encoder_counts_per_rev == 4096
    hw.configure(_config(encoder_counts_per_rev=0))
    assert hw.connect().encoder_counts_per_rev == 4096
    hw.configure(_config(encoder_counts_per_rev=2000))
    assert hw.connect().encoder_counts_per_rev == 2000
    with pytest.raises(HardwareError, match="ACK result 2"):
        hw.configure(_config(encoder_counts_per_rev=3))
    assert hw.connect().encoder_counts_per_rev == 2000
    hw.configure(_config())
    assert hw.clear()  # BAD_CONFIG, latched by the refusal


def test_set_encoder_moves_the_count_and_edges_continue_from_it(stepped: Stepped) -> None:
    hw = stepped.hw
    hw.set_encoder(-123_456)
    _, s = stepped.step(CommandFrame(0, 0, 0, 1))
    assert abs(s.encoder_count + 123_456) < 50  # the iris may still drift back on its spring
    for _ in range(300):  # open the iris: the count rises from the new value
        _, s = stepped.step(CommandFrame(3000, 0, 0, 1))
        if s.encoder_count > -123_456 + 40:
            break
    assert s.encoder_count > -123_456 + 40
    stepped.step(CommandFrame(0, 0, 0, 0))


def test_set_encoder_applies_to_the_range_of_motion_from_the_next_tick(stepped: Stepped) -> None:
    hw = stepped.hw
    hw.configure(_config(enc_min=-100, enc_max=100))
    hw.set_encoder(0)
    assert hw.clear()  # a range fault from the old count is gone now
    _, s = stepped.step(CommandFrame(0, 0, 0, 1))
    assert s.faults == 0 and abs(s.encoder_count) < 50  # the iris may still drift back on its spring
    hw.set_encoder(500)
    _, s = stepped.step(CommandFrame(0, 0, 0, 1))
    assert s.faults == Fault.RANGE_OF_MOTION and abs(s.encoder_count - 500) < 50
    hw.set_encoder(0)
    assert hw.clear()


@pytest.mark.parametrize(("rate", "period_us"), [(1000, 1000), (250, 4000), (300, 3000)])
def test_streams_one_sample_per_period_of_the_nearest_supported_rate(
        rig: tuple[Any, SerialHardware], rate: int, period_us: int) -> None:
    _, hw = rig
    hw.configure(_config(sample_rate_hz=rate))
    first = _fresh(hw)
    samples = [first] + [_next(hw) for _ in range(40)]
    assert [b.device_time_us - a.device_time_us for a, b in itertools.pairwise(samples)] == \
        [period_us] * 40
    assert [s.sample_index for s in samples] == list(range(first.sample_index, first.sample_index + 41))
    assert all(s.status & Status.STREAMING for s in samples)


def test_rate_zero_stops_streaming(rig: tuple[Any, SerialHardware]) -> None:
    _, hw = rig
    hw.configure(_config(sample_rate_hz=0))
    hw.discard_pending()  # sent before the ACK
    assert hw.read_sample(0.2) is None


def test_lockstep_sends_one_sample_per_command_one_period_apart(lockstep_rig: tuple[Any, SerialHardware]) -> None:
    _, hw = lockstep_rig
    hw.configure(_config(sample_rate_hz=500))
    samples = [_step(hw, CommandFrame(0, 0, 0, 1))[1] for _ in range(20)]
    assert [b.device_time_us - a.device_time_us for a, b in itertools.pairwise(samples)] == [2000] * 19
    assert hw.read_sample(0.1) is None


def test_command_is_applied_clamped_and_echoed(stepped: Stepped) -> None:
    hw = stepped.hw
    hw.configure(_config(max_duty=6000))
    seq, s = stepped.step(CommandFrame(2500, 7000, 0b10, 1))
    assert (s.duty0, s.duty1, s.direction, s.cmd_seq_echo) == (2500, 6000, 0b10, seq)
    assert s.status & Status.DUTY_CLAMPED and s.status & Status.PWM_ENABLED and s.status & Status.WATCHDOG_ARMED
    seq, s = stepped.step(CommandFrame(1000, 0, 0, 1))
    assert (s.duty0, s.duty1, s.cmd_seq_echo) == (1000, 0, seq) and not s.status & Status.DUTY_CLAMPED
    seq, s = stepped.step(CommandFrame(1000, 1000, 0, 0))
    assert (s.duty0, s.duty1, s.cmd_seq_echo) == (0, 0, seq) and not s.status & Status.PWM_ENABLED


def test_watchdog_trips_watchdog_ms_after_the_last_command_in_device_time(rig: tuple[Any, SerialHardware]) -> None:
    _, hw = rig
    hw.configure(_config(watchdog_ms=30))
    seq = hw.write_command(0.0)
    applied = _until(hw, lambda s: s.cmd_seq_echo == seq)
    assert applied.status & Status.WATCHDOG_ARMED
    tripped = _until(hw, lambda s: s.faults & Fault.WATCHDOG)
    elapsed_us = tripped.device_time_us - applied.device_time_us
    assert 29_000 <= elapsed_us <= 31_000
    assert not tripped.status & Status.WATCHDOG_ARMED and tripped.status & Status.FAULT_LATCHED
    assert FaultReport(Fault.WATCHDOG, Fault.WATCHDOG) in hw.faults_reported
    assert hw.clear()


def test_heating_time_trips_after_max_heating_ms_of_continuous_drive(rig: tuple[Any, SerialHardware]) -> None:
    _, hw = rig
    hw.configure(_config(max_heating_ms=40, watchdog_ms=2000))
    seq = hw.write_command(0.05)
    on = _until(hw, lambda s: s.cmd_seq_echo == seq)
    tripped = _until(hw, lambda s: s.faults != 0)
    assert tripped.faults == Fault.HEATING_TIME and (tripped.duty0, tripped.duty1) == (0, 0)
    assert 39_000 <= tripped.device_time_us - on.device_time_us <= 41_000
    assert hw.clear()


def test_a_force_above_the_limit_trips_and_cuts_pwm(stepped: Stepped) -> None:
    hw = stepped.hw
    _, rest = stepped.step(CommandFrame(0, 0, 0, 1))
    hw.configure(_config(force_limit_counts=rest.adc0 + 40, force_debounce_ms=3))
    _, s = stepped.step(CommandFrame(2000, 0, 0, 1))
    assert s.faults == 0 and s.duty0 == 2000
    stepped.device.control("input patient_torque_nm 1.0")  # A0 (the torque sensor) +100 counts
    try:
        for _ in range(200):
            _, s = stepped.step(CommandFrame(2000, 0, 0, 1))
            if s.faults:
                break
        assert s.faults == Fault.FORCE_LIMIT and s.duty0 == 0 and not s.status & Status.PWM_ENABLED
        echo = s.cmd_seq_echo
        _, s = stepped.step(CommandFrame(2000, 0, 0, 1))
        assert s.duty0 == 0 and s.cmd_seq_echo == echo  # ignored while latched
    finally:
        stepped.device.control("input patient_torque_nm 0.0")


def test_driving_out_of_the_range_of_motion_trips(stepped: Stepped) -> None:
    hw = stepped.hw
    _, rest = stepped.step(CommandFrame(0, 0, 0, 1))
    hw.configure(_config(enc_min=rest.encoder_count - 20, enc_max=rest.encoder_count + 20))
    for _ in range(500):
        _, s = stepped.step(CommandFrame(4000, 0, 0, 1))
        if s.faults:
            break
    assert s.faults == Fault.RANGE_OF_MOTION and s.duty0 == 0
    assert s.encoder_count > rest.encoder_count + 20


@pytest.mark.parametrize("limit", ["force", "range"])
def test_clear_is_refused_while_the_limit_is_violated(rig: tuple[Any, SerialHardware], limit: str) -> None:
    _, hw = rig
    now = _fresh(hw)
    if limit == "force":
        bad, fault = _config(force_limit_counts=max(0, now.adc0 - 100)), Fault.FORCE_LIMIT
    else:
        bad, fault = _config(enc_min=now.encoder_count + 1000, enc_max=now.encoder_count + 2000), Fault.RANGE_OF_MOTION
    hw.configure(bad)
    _until(hw, lambda s: s.faults & fault)
    assert not hw.clear()
    assert _fresh(hw).faults & fault
    hw.configure(_config())  # the limit lifted: the cause is gone
    assert hw.clear()
    assert _fresh(hw).faults == 0


def test_estop_input_pin_trips_and_holds_until_released(rig: tuple[Any, SerialHardware]) -> None:
    device, hw = rig
    if not hasattr(device, "set_estop_input"):
        pytest.skip("this backend cannot drive the e-stop pin")
    hw.configure(_config(flags=Configure.FLAG_ESTOP_INPUT | NC))
    hw.write_command(0.1)
    try:
        device.set_estop_input(True)
        s = _until(hw, lambda s: s.faults & Fault.ESTOP_INPUT)
        assert s.status & Status.ESTOP_INPUT_ACTIVE and s.duty0 == 0
        assert not hw.clear()
    finally:
        device.set_estop_input(False)
    _until(hw, lambda s: not s.status & Status.ESTOP_INPUT_ACTIVE)
    assert hw.clear()


def test_a_broken_estop_wire_is_a_stop_with_the_normally_closed_loop(rig: tuple[Any, SerialHardware]) -> None:
    device, hw = rig
    hw.configure(_config(flags=Configure.FLAG_ESTOP_INPUT | NC, watchdog_ms=1000))
    hw.write_command(0.1)
    _until(hw, lambda s: s.duty0 > 0)
    try:
        device.control("estop_wire broken")
        s = _until(hw, lambda s: s.faults & Fault.ESTOP_INPUT)
        assert s.duty0 == 0 and not s.status & Status.PWM_ENABLED
        assert not hw.clear()
    finally:
        device.control("estop_wire ok")
    _until(hw, lambda s: not s.status & Status.ESTOP_INPUT_ACTIVE)
    assert hw.clear()


def test_estop_command_latches_ignores_commands_until_clear(stepped: Stepped) -> None:
    hw = stepped.hw
    seq, s = stepped.step(CommandFrame(1000, 0, 0, 1))
    assert s.duty0 == 1000
    hw.estop()
    _, s = stepped.step(CommandFrame(1000, 0, 0, 1))
    assert s.faults == Fault.ESTOP_COMMAND and s.duty0 == 0 and s.cmd_seq_echo == seq
    assert hw.clear()
    seq, s = stepped.step(CommandFrame(1000, 0, 0, 1))
    assert s.faults == 0 and s.duty0 == 1000 and s.cmd_seq_echo == seq


def _packet(version: int, mtype: int, payload: bytes, seq: int = 1) -> bytes:
    body = bytes([version, mtype, seq & 0xFF, seq >> 8]) + payload
    crc = crc16_ccitt_false(body)
    return body + bytes([crc & 0xFF, crc >> 8])


def test_bad_frames_are_ignored_and_counted(stepped: Stepped) -> None:
    from cobs import cobs

    hw = stepped.hw
    _, before = stepped.step(CommandFrame(0, 0, 0, 1))
    bad = [
        b"\x01\x02\x03\x00",  # short
        encode_frame(CommandFrame(3000, 0, 0, 1), 9)[:6] + b"\x00",  # truncated
        cobs.encode(_packet(1, 0x03, bytes(6))[:-1] + b"\x01") + b"\x00",  # crc
        cobs.encode(_packet(9, 0x03, bytes(6))) + b"\x00",  # version
        cobs.encode(_packet(1, 0x42, b"")) + b"\x00",  # unknown type
        cobs.encode(_packet(1, 0x03, bytes(4))) + b"\x00",  # length
        b"\x07" * 80 + b"\x00",  # overflow
        encode_frame(Sample(*([0] * 12)), 5),  # a valid device->host type is unknown to the device
    ]
    hw.send_raw(b"".join(bad))
    seq, s = stepped.step(CommandFrame(3000, 0, 0, 1))
    assert s.rx_bad_frames - before.rx_bad_frames == len(bad)
    assert (s.duty0, s.cmd_seq_echo) == (3000, seq)
    assert hw.clear()
