"""The firmware behaviour as a state machine: handshake, commands, every safety trip, CLEAR rules."""

from __future__ import annotations

import pytest

from rehab_hil.devices.core import DeviceCore, Readings
from rehab_hil.protocol import (
    Ack,
    AckResult,
    Clear,
    CommandFrame,
    Configure,
    DeviceHeartbeat,
    EStop,
    Fault,
    FaultReport,
    Frame,
    Heartbeat,
    Hello,
    HelloReq,
    ResetCause,
    Sample,
    Status,
)

OK = Readings(encoder_count=0, adc0=500, adc1=0)


def _config(**kw: int) -> Configure:
    base = dict(sample_rate_hz=1000, watchdog_ms=50, max_duty=8000, max_heating_ms=10_000,
                force_limit_counts=900, enc_min=-1000, enc_max=1000, flags=Configure.FLAG_ESTOP_INPUT)
    base.update(kw)
    return Configure(**base)


def _configured(**kw: int) -> DeviceCore:
    core = DeviceCore(2000)
    assert core.on_frame(Frame(0, _config(**kw))) == [Ack(Configure.TYPE, 0, AckResult.OK)]
    return core


def _samples(msgs: list) -> list[Sample]:
    return [m for m in msgs if isinstance(m, Sample)]


def _faults(msgs: list) -> list[FaultReport]:
    return [m for m in msgs if isinstance(m, FaultReport)]


def test_boot_sends_hello_and_answers_hello_requests() -> None:
    core = DeviceCore(2000)
    (hello,) = core.boot()
    assert isinstance(hello, Hello) and hello.encoder_counts_per_rev == 2000 and hello.reset_cause == 1
    assert core.on_frame(Frame(3, HelloReq())) == [hello]


def test_boot_after_a_hardware_watchdog_reset_latches_the_fault() -> None:
    core = DeviceCore(2000, reset_cause=ResetCause.HW_WATCHDOG)
    assert core.boot()[1] == FaultReport(Fault.HW_WATCHDOG_RESET, Fault.HW_WATCHDOG_RESET)


def test_commands_before_configure_are_ignored() -> None:
    core = DeviceCore(2000)
    core.on_frame(Frame(1, CommandFrame(5000, 0, 0, 1)))
    assert core.duty == [0, 0] and not core.armed and core.tick(OK) == []


@pytest.mark.parametrize(("rate", "every"), [(1000, 1), (250, 4), (100, 10), (0, None)])
def test_samples_stream_every_kth_tick(rate: int, every: int | None) -> None:
    core = _configured(sample_rate_hz=rate)
    ticks = [i for i in range(1, 41) if _samples(core.tick(OK))]
    assert ticks == ([] if every is None else list(range(every, 41, every)))


def test_command_is_applied_clamped_and_echoed() -> None:
    core = _configured(max_duty=8000)
    core.on_frame(Frame(7, CommandFrame(9000, 100, 0b11, 1)))
    (s,) = _samples(core.tick(OK))
    assert (s.duty0, s.duty1, s.direction, s.cmd_seq_echo) == (8000, 100, 0b11, 7)
    assert s.status & Status.DUTY_CLAMPED and s.status & Status.PWM_ENABLED and s.status & Status.WATCHDOG_ARMED


def test_enable_zero_turns_every_output_off() -> None:
    core = _configured()
    core.on_frame(Frame(1, CommandFrame(3000, 3000, 0, 1)))
    core.on_frame(Frame(2, CommandFrame(3000, 3000, 0, 0)))
    (s,) = _samples(core.tick(OK))
    assert (s.duty0, s.duty1, s.cmd_seq_echo) == (0, 0, 2) and not s.status & Status.PWM_ENABLED


def test_watchdog_trips_after_exactly_watchdog_ms_of_ticks_without_a_command() -> None:
    core = _configured(watchdog_ms=20)
    core.on_frame(Frame(1, CommandFrame(3000, 0, 0, 1)))
    trip_tick = next(i for i in range(1, 100) if _faults(core.tick(OK)))
    assert trip_tick == 20
    assert core.duty == [0, 0] and core.faults == Fault.WATCHDOG and not core.armed


def test_heartbeat_does_not_feed_the_watchdog() -> None:
    core = _configured(watchdog_ms=5)
    core.on_frame(Frame(1, CommandFrame(3000, 0, 0, 1)))
    for _ in range(4):
        assert core.on_frame(Frame(2, Heartbeat(0))) == [DeviceHeartbeat(core.uptime_ms)]
        core.tick(OK)
    assert _faults(core.tick(OK)) == [FaultReport(Fault.WATCHDOG, Fault.WATCHDOG)]


def test_heating_time_trips_after_continuous_drive() -> None:
    core = _configured(max_heating_ms=30, watchdog_ms=1000)
    core.on_frame(Frame(1, CommandFrame(100, 0, 0, 1)))
    trip = next(i for i in range(1, 100) if _faults(core.tick(OK)))
    assert trip == 30 and core.faults == Fault.HEATING_TIME


def test_heating_counter_restarts_when_the_drive_pauses() -> None:
    core = _configured(max_heating_ms=30, watchdog_ms=1000)
    core.on_frame(Frame(1, CommandFrame(100, 0, 0, 1)))
    for _ in range(20):
        core.tick(OK)
    core.on_frame(Frame(2, CommandFrame(0, 0, 0, 1)))
    core.tick(OK)
    core.on_frame(Frame(3, CommandFrame(100, 0, 0, 1)))
    assert not any(_faults(core.tick(OK)) for _ in range(29))
    assert _faults(core.tick(OK))


@pytest.mark.parametrize(("readings", "fault"), [
    (Readings(0, 901, 0), Fault.FORCE_LIMIT),
    (Readings(1001, 500, 0), Fault.RANGE_OF_MOTION),
    (Readings(-1001, 500, 0), Fault.RANGE_OF_MOTION),
    (Readings(0, 500, 0, estop_pin=True), Fault.ESTOP_INPUT),
])
def test_limit_trips_cut_pwm_and_clear_refuses_while_the_cause_holds(readings: Readings, fault: int) -> None:
    core = _configured(watchdog_ms=1000)
    core.on_frame(Frame(1, CommandFrame(3000, 0, 0, 1)))
    assert _faults(core.tick(readings)) == [FaultReport(fault, fault)]
    assert core.duty == [0, 0]
    core.on_frame(Frame(2, CommandFrame(3000, 0, 0, 1)))  # ignored while latched
    assert core.duty == [0, 0] and core.cmd_seq_echo == 1
    assert core.on_frame(Frame(3, Clear())) == [Ack(Clear.TYPE, 3, AckResult.REFUSED)]
    core.tick(OK)
    assert core.on_frame(Frame(4, Clear())) == [Ack(Clear.TYPE, 4, AckResult.OK)]
    assert core.faults == 0 and core.duty == [0, 0]


def test_estop_pin_is_ignored_unless_enabled_but_always_reported() -> None:
    core = _configured(flags=0)
    (s,) = _samples(core.tick(Readings(0, 500, 0, estop_pin=True)))
    assert s.faults == 0 and s.status & Status.ESTOP_INPUT_ACTIVE


NC = Configure.FLAG_ESTOP_INPUT | Configure.FLAG_ESTOP_NORMALLY_CLOSED


@pytest.mark.parametrize(("flags", "readings", "trips"), [
    (NC, Readings(0, 500, 0), False),  # loop closed: released
    (NC, Readings(0, 500, 0, estop_pin=True), True),  # button opens the loop
    (NC, Readings(0, 500, 0, estop_wire_broken=True), True),  # a broken wire is a stop
    (Configure.FLAG_ESTOP_INPUT, Readings(0, 500, 0, estop_wire_broken=True), False),  # normally open: the hazard
])
def test_a_normally_closed_estop_loop_trips_on_a_press_and_on_a_broken_wire(flags: int, readings: Readings,
                                                                            trips: bool) -> None:
    core = _configured(flags=flags, watchdog_ms=1000)
    core.on_frame(Frame(1, CommandFrame(3000, 0, 0, 1)))
    out = core.tick(readings)
    assert bool(_faults(out)) is trips and (core.duty == [0, 0]) is trips
    (s,) = _samples(out)
    assert bool(s.status & Status.ESTOP_INPUT_ACTIVE) is trips


def test_force_limit_is_debounced_a_noise_burst_does_not_trip_a_real_overload_does() -> None:
    core = _configured(watchdog_ms=1000, force_debounce_ms=3)
    core.on_frame(Frame(1, CommandFrame(3000, 0, 0, 1)))
    high = Readings(0, 1000, 0)
    for _ in range(5):  # bursts of 2 ticks above the limit, separated by one normal tick
        assert not _faults(core.tick(high)) and not _faults(core.tick(high))
        assert not _faults(core.tick(OK))
    assert core.duty == [3000, 0]
    assert not _faults(core.tick(high)) and not _faults(core.tick(high))
    assert _faults(core.tick(high)) == [FaultReport(Fault.FORCE_LIMIT, Fault.FORCE_LIMIT)]  # the 3rd in a row
    assert core.duty == [0, 0]


def test_estop_command_latches_and_clear_releases_it() -> None:
    core = _configured()
    core.on_frame(Frame(1, CommandFrame(3000, 0, 0, 1)))
    out = core.on_frame(Frame(2, EStop()))
    assert FaultReport(Fault.ESTOP_COMMAND, Fault.ESTOP_COMMAND) in out
    assert Ack(EStop.TYPE, 2, AckResult.OK) in out and core.duty == [0, 0]
    assert core.on_frame(Frame(3, Clear())) == [Ack(Clear.TYPE, 3, AckResult.OK)]


@pytest.mark.parametrize("bad", [dict(watchdog_ms=0), dict(max_duty=10001), dict(max_heating_ms=0),
                                 dict(force_limit_counts=1024), dict(enc_min=5, enc_max=5)])
def test_invalid_configure_is_refused_and_latches_bad_config(bad: dict) -> None:
    core = DeviceCore(2000)
    out = core.on_frame(Frame(1, _config(**bad)))
    assert Ack(Configure.TYPE, 1, AckResult.BAD_PARAMETER) in out
    assert core.faults == Fault.BAD_CONFIG and core.config is None


def test_device_to_host_types_sent_to_the_device_count_as_bad_frames() -> None:
    core = DeviceCore(2000)
    core.on_frame(Frame(1, DeviceHeartbeat(5)))
    assert core.rx_bad_frames == 1
