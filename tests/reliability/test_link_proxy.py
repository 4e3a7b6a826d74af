"""The fault proxy delivers the faults it is asked for, also when the reader is slow."""

from __future__ import annotations

import os
import tty

from rehab_hil.protocol import Fault, FaultReport, Sample, encode_frame

from .link_proxy import OUT_CAP, DeviceTap, _Engine


def _read_all(fd: int) -> bytes:
    got = bytearray()
    while True:
        try:
            chunk = os.read(fd, 65536)
        except BlockingIOError:
            return bytes(got)
        if not chunk:
            return bytes(got)
        got += chunk


def test_a_garbage_burst_waits_for_room_instead_of_being_lost_to_the_overrun() -> None:
    dev_master, dev_slave = os.openpty()  # the device's end: the proxy opens its slave, as it would a device
    engine = _Engine(os.ttyname(dev_slave))
    host = os.open(engine.port, os.O_RDWR | os.O_NOCTTY | os.O_NONBLOCK)
    tty.setraw(host)
    try:
        sent = 0
        while len(engine._out[True]) < OUT_CAP // 2:  # a host that stopped reading: its pty fills, then the queue
            engine._pass(b"\x11" * 256, engine.down, downward=True)
            sent += 256
        engine.down.garbage = 3000  # more than the queue has room for now
        engine._pass(b"\x22" * 100, engine.down, downward=True)
        sent += 100
        assert engine.down.injected["overrun_bytes"] == 0  # the data still fit; the burst did not go in with it
        received = _read_all(host)  # the host catches up
        while engine._out[True]:
            engine._flush(True)
            received += _read_all(host)
        engine._pass(b"\x33" * 10, engine.down, downward=True)  # the next chunk carries the burst
        received += _read_all(host)
        assert engine.down.injected["garbage_bytes"] == 3000
        assert engine.down.injected["overrun_bytes"] == 0
        assert len(received) == sent + 3000 + 10  # everything, the burst included, reached the host
        assert received.endswith(b"\x33" * 10)
    finally:
        os.close(host)
        engine.unplug()
        for fd in (engine.dev, dev_master, dev_slave):
            os.close(fd)


def test_frames_to_truncate_are_not_spent_on_a_chunk_the_overrun_loses() -> None:
    dev_master, dev_slave = os.openpty()
    engine = _Engine(os.ttyname(dev_slave))
    host = os.open(engine.port, os.O_RDWR | os.O_NOCTTY | os.O_NONBLOCK)
    tty.setraw(host)
    try:
        while len(engine._out[True]) < OUT_CAP - 100:  # the host stopped reading: the queue is all but full
            engine._pass(b"\x11" * 50, engine.down, downward=True)
        engine.down.truncate = 5
        frames = (b"\x05" * 20 + b"\x00") * 20  # 420 bytes of frames: the overrun loses the chunk whole
        engine._pass(frames, engine.down, downward=True)
        assert engine.down.injected["overrun_bytes"] == len(frames)
        assert engine.down.truncate == 5 and engine.down.injected["truncated_frames"] == 0
    finally:
        os.close(host)
        engine.unplug()
        for fd in (engine.dev, dev_master, dev_slave):
            os.close(fd)



def _sample(index: int, faults: int = 0) -> bytes:
    return encode_frame(Sample(1000 * index, index, 0, 0, 0, 0, 0, 0, 1, faults, 0, 0), index)


def _watchdog_report() -> bytes:
    return encode_frame(FaultReport(Fault.WATCHDOG, Fault.WATCHDOG), 0)


def test_a_trip_reported_before_its_first_sample_is_not_an_unreported_one() -> None:
    tap = DeviceTap()
    tap.feed(_sample(1) + _watchdog_report() + _sample(2, Fault.WATCHDOG) + _sample(3, Fault.WATCHDOG))
    assert tap.unreported_trips == []
    assert [r.faults for r in tap.fault_reports] == [Fault.WATCHDOG]


def test_a_trip_whose_report_never_came_over_a_whole_stream_is_flagged_as_such() -> None:
    tap = DeviceTap()
    tap.feed(_sample(1))
    tap.feed(_sample(2, Fault.WATCHDOG))  # nothing lost between: the device did not report it
    assert tap.unreported_trips == [(Fault.WATCHDOG, True)]


def test_a_report_lost_before_the_tap_is_told_apart_from_one_never_sent() -> None:
    report = _watchdog_report()
    damaged = DeviceTap()  # bytes from the middle of the FAULT frame lost (a full pty): one bad frame
    damaged.feed(_sample(1) + report[:3])
    damaged.feed(report[-2:] + _sample(2, Fault.WATCHDOG))
    assert damaged.decoder.bad_total == 1
    assert damaged.unreported_trips == [(Fault.WATCHDOG, False)]
    dropped = DeviceTap()  # whole frames lost: the report and a SAMPLE with it
    dropped.feed(_sample(1) + _sample(3, Fault.WATCHDOG))
    assert dropped.unreported_trips == [(Fault.WATCHDOG, False)]
    cleared = DeviceTap()  # a latch cleared and tripped again is a new trip, owed a new report
    cleared.feed(_sample(1) + report + _sample(2, Fault.WATCHDOG) + _sample(3) + _sample(4, Fault.WATCHDOG))
    assert cleared.unreported_trips == [(Fault.WATCHDOG, True)]
