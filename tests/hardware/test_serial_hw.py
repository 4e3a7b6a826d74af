"""SerialHardware on a real pty: the test plays the device by writing and reading raw frames."""

from __future__ import annotations

import os
import select
import termios
import threading
import time
import tty
from collections.abc import Iterator

import pytest

from rehab_hil.hardware import Arrival, HardwareError, LifecycleState, SerialHardware, configure_from_config, duty_units
from rehab_hil.loading import load_config
from rehab_hil.protocol import (
    Ack,
    AckResult,
    Clear,
    CommandFrame,
    Configure,
    FrameDecoder,
    Hello,
    HelloReq,
    Sample,
    encode_frame,
)

HELLO = Hello(1, 1, 0, 0, 2, 2, 2000, 5000, 10, 1000, 1)


class PtyPeer:
    """The device end of a raw pty: read host frames, write device frames."""

    def __init__(self) -> None:
        self.master, self.slave = os.openpty()
        tty.setraw(self.slave, termios.TCSANOW)
        self.path = os.ttyname(self.slave)
        self.decoder = FrameDecoder()
        self.seq = 0

    def send(self, *msgs: object, seq: int | None = None) -> None:
        for m in msgs:
            os.write(self.master, encode_frame(m, self.seq if seq is None else seq))  # type: ignore[arg-type]
            self.seq += 1

    def receive(self, timeout: float = 2.0) -> list:
        ready, _, _ = select.select([self.master], [], [], timeout)
        return self.decoder.feed(os.read(self.master, 4096)) if ready else []

    def close(self) -> None:
        for fd in (self.master, self.slave):
            try:
                os.close(fd)
            except OSError:
                pass


@pytest.fixture
def peer() -> Iterator[PtyPeer]:
    p = PtyPeer()
    yield p
    p.close()


def _answer(peer: PtyPeer, reply: object | None = None) -> threading.Thread:
    """Answer the host's next request in the background (HELLO for HELLO_REQ, else ``reply``)."""

    def run() -> None:
        for _ in range(20):
            for frame in peer.receive(0.25):
                if isinstance(frame.msg, HelloReq):
                    peer.send(HELLO)
                    return
                if reply is not None:
                    msg = reply(frame) if callable(reply) else reply
                    peer.send(msg)
                    return

    t = threading.Thread(target=run, daemon=True)
    t.start()
    return t


def _connected(peer: PtyPeer) -> SerialHardware:
    hw = SerialHardware(peer.path)
    t = _answer(peer)
    assert hw.connect(timeout=3.0) == HELLO
    t.join()
    return hw


def _sample(index: int, echo: int = 0, **kw: int) -> Sample:
    base = dict(device_time_us=index * 1000, sample_index=index, encoder_count=0, adc0=512, adc1=0, duty0=0,
                duty1=0, direction=0, status=1, faults=0, cmd_seq_echo=echo, rx_bad_frames=0)
    base.update(kw)
    return Sample(**base)


def test_connect_handshakes_and_reports_capabilities(peer: PtyPeer) -> None:
    with _connected(peer) as hw:
        assert hw.info == HELLO


def test_connect_without_an_answer_raises_a_clear_error(peer: PtyPeer) -> None:
    with SerialHardware(peer.path) as hw, pytest.raises(HardwareError, match="no HELLO"):
        hw.connect(timeout=0.3)


def test_opening_a_missing_port_raises_hardware_error(tmp_path: os.PathLike) -> None:
    with pytest.raises(HardwareError, match="cannot open"):
        SerialHardware(str(tmp_path) + "/nope").connect(timeout=0.1)


def test_samples_arrive_in_order_and_gaps_count_as_dropped(peer: PtyPeer) -> None:
    hw = _connected(peer)
    peer.send(*(_sample(i) for i in (10, 11, 14, 15)))
    got = [hw.read_sample(1.0).sample_index for _ in range(4)]
    assert got == [10, 11, 14, 15]
    assert hw.stats.dropped_samples == 2 and hw.stats.samples == 4
    assert hw.read_sample(0.05) is None
    hw.close()


def test_a_read_brings_each_samples_arrival_time_and_the_gap_before_it(peer: PtyPeer) -> None:
    """``read`` returns (host time, sample, gap) in one value: the arrival is taken when the bytes
    came off the link (before the read), and the samples dropped before one come with it."""
    hw = _connected(peer)
    sent = time.perf_counter()
    peer.send(*(_sample(i) for i in (10, 11, 14)))
    time.sleep(0.05)  # the frames wait in the OS buffer: the arrival is when they are read, before the return
    arrivals = [hw.read(1.0) for _ in range(3)]
    returned = time.perf_counter()
    assert all(isinstance(a, Arrival) for a in arrivals)
    assert [(a.sample.sample_index, a.gap) for a in arrivals] == [(10, 0), (11, 0), (14, 2)]
    assert all(sent < a.host_time_s <= returned for a in arrivals)
    t, sample, gap = arrivals[2]  # a plain tuple to unpack
    assert (t, sample, gap) == (arrivals[2].host_time_s, arrivals[2].sample, 2)
    assert hw.stats.dropped_samples == 2 and hw.read(0.05) is None
    hw.close()


def test_read_sample_keeps_the_arrival_and_gap_in_attributes_for_its_callers(peer: PtyPeer) -> None:
    hw = _connected(peer)
    peer.send(_sample(3), _sample(7))
    first = hw.read(1.0)
    assert first is not None and (first.sample.sample_index, first.gap) == (3, 0)
    assert (hw.last_sample_time, hw.last_sample_gap) == (0.0, 0)  # read writes no attribute
    s = hw.read_sample(1.0)
    assert s is not None and s.sample_index == 7
    assert hw.last_sample_gap == 3 and first.host_time_s <= hw.last_sample_time <= time.perf_counter()
    hw.close()
    with pytest.raises(HardwareError, match=r"read_sample: the hardware is finalized"):
        hw.read_sample(0.0)
    with pytest.raises(HardwareError, match=r"read: the hardware is finalized"):
        hw.read(0.0)


def test_a_read_that_does_not_wait_returns_none_on_a_quiet_link_and_the_sample_once_it_is_there(
        peer: PtyPeer) -> None:
    hw = _connected(peer)  # host pacing takes what arrived without waiting, every tick
    assert [hw.read_sample(0.0) for _ in range(3)] == [None, None, None]
    peer.send(_sample(7))
    for _ in range(2000):  # the pty delivers the frame shortly after the write
        s = hw.read_sample(0.0)
        if s is not None:
            break
        time.sleep(0.001)
    assert s is not None and s.sample_index == 7 and hw.read_sample(0.0) is None
    hw.close()


def test_garbage_and_corrupt_frames_are_counted_and_skipped(peer: PtyPeer) -> None:
    hw = _connected(peer)
    bad = bytearray(encode_frame(_sample(1), 0))
    bad[5] ^= 0xFF
    os.write(peer.master, b"\x13\x37garbage\x00" + bytes(bad))
    peer.send(_sample(2))
    assert hw.read_sample(1.0).sample_index == 2
    assert hw.stats.bad_frames.total() == 2
    hw.close()


def test_command_echo_gives_a_latency(peer: PtyPeer) -> None:
    hw = _connected(peer)
    _answer(peer, lambda f: Ack(Configure.TYPE, f.seq, AckResult.OK))
    hw.configure(Configure(1000, 50, 10000, 1000, 1023, -1, 1, 0))  # write_command needs ACTIVE
    seq = hw.write_command(0.25, direction=1)
    (frame,) = [f for f in peer.receive() if isinstance(f.msg, CommandFrame)]
    assert frame.seq == seq and frame.msg == CommandFrame(2500, 0, 1, 1)
    peer.send(_sample(1, echo=seq, duty0=2500))
    assert hw.read_sample(1.0).cmd_seq_echo == seq
    assert len(hw.stats.latencies_s) == 1 and hw.stats.latencies_s[0] > 0
    hw.close()


def test_configure_refused_by_the_device_raises(peer: PtyPeer) -> None:
    hw = _connected(peer)
    _answer(peer, lambda f: Ack(Configure.TYPE, f.seq, AckResult.BAD_PARAMETER))
    with pytest.raises(HardwareError, match="refused"):
        hw.configure(Configure(1000, 0, 10000, 1000, 1023, -1, 1, 0))
    hw.close()


def test_deactivate_stops_streaming_and_pwm_with_the_limits_kept(peer: PtyPeer) -> None:
    """ACTIVE -> INACTIVE: one CONFIGURE at rate 0 and max duty 0 with the session's other fields,
    acknowledged; commands are refused until the next configure."""
    hw = _connected(peer)
    with pytest.raises(HardwareError, match="no CONFIGURE acknowledged yet"):
        hw.deactivate()  # nothing to take the limits from
    session = Configure(1000, 50, 8000, 1000, 700, -28, 723, Configure.FLAG_ESTOP_INPUT, 3, 2000)
    _answer(peer, lambda f: Ack(Configure.TYPE, f.seq, AckResult.OK))
    hw.configure(session)
    seen: list[Configure] = []
    _answer(peer, lambda f: seen.append(f.msg) or Ack(Configure.TYPE, f.seq, AckResult.OK))
    hw.deactivate(timeout=2.0)
    assert seen == [Configure(0, 50, 0, 1000, 700, -28, 723, Configure.FLAG_ESTOP_INPUT, 3, 2000)]
    assert hw.state is LifecycleState.INACTIVE
    with pytest.raises(HardwareError, match=r"write_command: the hardware is inactive; call configure\(\) first"):
        hw.write_command(0.1)
    wide = Configure(1000, 50, 8000, 1000, 1023, -10**6, 10**6)  # or the limits of a given CONFIGURE
    _answer(peer, lambda f: seen.append(f.msg) or Ack(Configure.TYPE, f.seq, AckResult.OK))
    hw.deactivate(wide, timeout=2.0)
    assert seen[-1] == Configure(0, 50, 0, 1000, 1023, -10**6, 10**6) and hw.state is LifecycleState.INACTIVE
    _answer(peer, lambda f: Ack(Configure.TYPE, f.seq, AckResult.BAD_PARAMETER))
    with pytest.raises(HardwareError, match="refused"):
        hw.deactivate(timeout=2.0)
    hw.close()


def test_clear_reports_whether_faults_remain(peer: PtyPeer) -> None:
    hw = _connected(peer)
    _answer(peer, lambda f: Ack(Clear.TYPE, f.seq, AckResult.REFUSED))
    assert hw.clear() is False
    hw.close()


def test_request_without_ack_times_out_with_hardware_error(peer: PtyPeer) -> None:
    hw = _connected(peer)
    with pytest.raises(HardwareError, match="no ACK"):
        hw.estop(timeout=0.2)
    hw.close()


def test_a_request_whose_frame_was_lost_is_sent_again_and_its_ack_taken(peer: PtyPeer) -> None:
    """A CONFIGURE lost on the way (a byte dropped in the 328P's 2-byte receive buffer) is never
    acknowledged: the host sends it again with a new seq and takes that copy's ACK."""
    hw = _connected(peer)
    seen: list[int] = []

    def device() -> None:
        for _ in range(40):
            for frame in peer.receive(0.1):
                if isinstance(frame.msg, Configure):
                    seen.append(frame.seq)
                    if len(seen) == 2:  # the first copy is "lost": only the second is answered
                        peer.send(Ack(Configure.TYPE, frame.seq, AckResult.OK))
                        return

    t = threading.Thread(target=device, daemon=True)
    t.start()
    hw.configure(Configure(1000, 0, 10000, 1000, 1023, -1, 1, 0), timeout=3.0)
    t.join()
    assert len(seen) == 2 and seen[0] != seen[1]
    assert hw.stats.request_resends == 1
    hw.close()


def test_connecting_to_a_device_in_virtual_time_asks_for_its_hello_once_however_late_it_comes(
        peer: PtyPeer) -> None:
    """A simulated AVR slow to start on a loaded machine: a second HELLO_REQ would enter its UART as
    one more frame and move every later one in device time (a lockstep session then differed from
    the idle machine's: the first COMMAND missed its tick)."""
    asked: list[int] = []

    def device() -> None:
        t_end = time.perf_counter() + 0.8
        while time.perf_counter() < t_end:
            asked.extend(f.seq for f in peer.receive(0.1) if isinstance(f.msg, HelloReq))
        peer.send(HELLO)

    t = threading.Thread(target=device, daemon=True)
    t.start()
    with SerialHardware(peer.path, resend_s=None) as hw:
        assert hw.connect(timeout=3.0) == HELLO
    t.join()
    assert len(asked) == 1  # the default asks every 0.25 s: three or four times by then


def test_a_request_to_a_device_in_virtual_time_is_sent_once_however_late_its_ack(peer: PtyPeer) -> None:
    """``resend_s=None`` (a lockstep device: its pty loses nothing, and a copy sent again would enter
    its UART as one more frame, costing device time): a CONFIGURE answered after 1.3 s, while a
    loaded machine starved the device, went out once."""
    hw = SerialHardware(peer.path, resend_s=None)
    t = _answer(peer)
    hw.connect(timeout=2.0)
    t.join()
    seen: list[int] = []

    def device() -> None:
        t_end = time.perf_counter() + 1.3
        while time.perf_counter() < t_end:
            seen.extend(f.seq for f in peer.receive(0.1) if isinstance(f.msg, Configure))
        peer.send(Ack(Configure.TYPE, seen[0], AckResult.OK))

    t = threading.Thread(target=device, daemon=True)
    t.start()
    hw.configure(Configure(1000, 0, 10000, 1000, 1023, -1, 1, 0), timeout=3.0)
    t.join()
    assert len(seen) == 1  # the default (0.5 s) would have sent two more copies
    assert hw.stats.request_resends == 0
    hw.close()


def test_a_request_answered_late_returns_only_once_its_last_copy_is_answered(peer: PtyPeer) -> None:
    """A slow device acknowledges both copies: the request returns after the last copy's ACK, so no copy
    still on its way can restart the stream after the caller went on."""
    hw = _connected(peer)
    sent_second_ack = threading.Event()

    def device() -> None:
        copies: list[int] = []
        for _ in range(40):
            for frame in peer.receive(0.1):
                if isinstance(frame.msg, Clear):
                    copies.append(frame.seq)
            if len(copies) == 2:
                peer.send(Ack(Clear.TYPE, copies[0], AckResult.OK))
                time.sleep(0.3)
                sent_second_ack.set()
                peer.send(Ack(Clear.TYPE, copies[1], AckResult.OK))
                return

    t = threading.Thread(target=device, daemon=True)
    t.start()
    assert hw.clear(timeout=3.0) is True
    assert sent_second_ack.is_set()
    t.join()
    assert hw.stats.request_resends == 1
    hw.close()


def test_a_request_whose_first_ack_was_lost_returns_on_the_last_copys_ack(peer: PtyPeer) -> None:
    """The first copy's ACK corrupted on the way, the second copy's ACK arrives: the link keeps
    order, so nothing is still on its way and the request returns at once instead of waiting out
    its timeout for an ACK that will never come (a firmware test saw 5 s of samples pile up)."""
    hw = _connected(peer)
    answered = threading.Event()

    def device() -> None:
        copies: list[int] = []
        for _ in range(40):
            copies.extend(f.seq for f in peer.receive(0.1) if isinstance(f.msg, Configure))
            if len(copies) == 2:
                peer.send(Ack(Configure.TYPE, copies[1], AckResult.OK))
                answered.set()
                return

    t = threading.Thread(target=device, daemon=True)
    t.start()
    started = time.perf_counter()
    hw.configure(Configure(1000, 0, 10000, 1000, 1023, -1, 1, 0), timeout=30.0)
    waited = time.perf_counter() - started
    t.join()
    assert answered.is_set() and hw.stats.request_resends == 1
    assert waited < 15.0  # the old rule waited the whole 30 s for the first copy's ACK
    hw.close()


def test_unsolicited_hello_counts_as_a_reboot(peer: PtyPeer) -> None:
    hw = _connected(peer)
    peer.send(HELLO, seq=0)
    peer.send(_sample(0))
    assert hw.read_sample(1.0).sample_index == 0
    assert hw.stats.reboots == 1 and hw.stats.dropped_samples == 0
    hw.close()


def test_device_going_away_raises_hardware_error(peer: PtyPeer) -> None:
    hw = _connected(peer)
    peer.close()
    with pytest.raises(HardwareError, match="lost"):
        for _ in range(10):
            hw.read_sample(0.1)
    hw.close()


@pytest.mark.parametrize("bad", [float("nan"), float("inf")])
def test_non_finite_duty_is_refused(bad: float) -> None:
    with pytest.raises(ValueError, match="finite"):
        duty_units(bad)


def test_duty_is_clipped_to_the_unit_range() -> None:
    assert [duty_units(d) for d in (-0.5, 0.0, 0.33333, 1.0, 7.0)] == [0, 0, 3333, 10000, 10000]


@pytest.mark.slow  # importing the plant configs pulls in python-control and scipy
def test_configure_from_config_converts_limits_to_counts(configs_dir: os.PathLike) -> None:
    cfg = load_config(f"{configs_dir}/finger_extensor.toml")
    c = configure_from_config(cfg, encoder_counts_per_rev=2000)
    assert (c.sample_rate_hz, c.watchdog_ms, c.max_duty) == (1000, 50, 10000)
    assert (c.enc_min, c.enc_max) == (-28, 723)  # -5 deg and 130 deg at 2000 counts/rev, rounded outward
    assert c.max_heating_ms == 600_000 and c.force_limit_counts == 1023
