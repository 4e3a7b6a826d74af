"""Virtual time (``clock="lockstep"``): the same COMMANDs give the same SAMPLEs, field for field,
on an idle machine and beside two busy processes, for the Python device and for the firmware in
simavr. This is what lets the tests of logic pass on a loaded CI machine."""

from __future__ import annotations

import itertools
import subprocess
import time
from collections.abc import Iterator
from contextlib import contextmanager
from typing import Any

import pytest
from cobs import cobs

from rehab_hil.devices import spawn_device
from rehab_hil.hardware import SerialHardware
from rehab_hil.protocol import CommandFrame, Configure, crc16_ccitt_false

from .conftest import CONFIG, avr_skip_reason

pytestmark = [pytest.mark.slow, pytest.mark.xdist_group("sim_devices")]

WIDE = 1 << 30


@contextmanager
def busy_cores(n: int = 2) -> Iterator[None]:
    """``n`` processes that spin for as long as the block runs (one per core of this machine)."""
    procs = [subprocess.Popen(["sh", "-c", "while :; do :; done"]) for _ in range(n)]
    try:
        yield
    finally:
        for p in procs:
            p.kill()
            p.wait()


@contextmanager
def _lockstep_device(kind: str, watchdog_ms: int) -> Iterator[tuple[Any, SerialHardware]]:
    """A fresh lockstep device, connected and streaming at 1 kHz, wide open."""
    dev = spawn_device(kind, CONFIG, clock="lockstep")
    hw = SerialHardware(dev.port, write_timeout_s=5.0, resend_s=None)  # a CONFIGURE sent again costs device time
    try:
        hw.connect(timeout=20.0)
        hw.configure(Configure(1000, watchdog_ms, 10000, 60_000, 1023, -WIDE, WIDE, 0), timeout=20.0)
        hw.discard_pending()
        yield dev, hw
    finally:
        hw.close()
        dev.close()


def _session(kind: str) -> list[tuple[int, ...]]:
    """A fresh device, 250 samples at 1 kHz under a duty staircase, the rig's 50 ms watchdog on."""
    with _lockstep_device(kind, 50) as (dev, hw):
        out = []
        for i in range(250):
            seq = hw.send_command(CommandFrame(500 * ((i // 25) % 8), 0, (i // 125) % 2, 1))
            s = hw.read_sample(20.0)
            assert s is not None, dev.control("status")
            out.append((s.device_time_us, s.sample_index, s.encoder_count, s.adc0, s.adc1, s.duty0, s.direction,
                        s.status, s.faults, s.cmd_seq_echo == seq))
        return out


@pytest.mark.parametrize("kind", ["sim", "avr"])
def test_a_lockstep_session_is_the_same_on_an_idle_and_on_a_fully_loaded_machine(kind: str) -> None:
    if kind == "avr" and (reason := avr_skip_reason()):
        pytest.skip(reason)
    quiet = _session(kind)
    with busy_cores(2):
        loaded = _session(kind)
    assert loaded == quiet
    assert all(s[8] == 0 for s in quiet)  # no watchdog trip: the host's pauses cost no device time
    assert all(s[9] for s in quiet)  # each SAMPLE answers the COMMAND just sent
    assert max(s[2] for s in quiet) - min(s[2] for s in quiet) > 20  # the plant moved under the duty


def _frame(mtype: int, payload: bytes, seq: int = 1, version: int = 1) -> bytes:
    """A COBS frame with a good CRC, whatever its type and payload."""
    body = bytes([version, mtype, seq & 0xFF, seq >> 8]) + payload
    crc = crc16_ccitt_false(body)
    return cobs.encode(body + bytes([crc & 0xFF, crc >> 8])) + b"\x00"


@pytest.mark.parametrize("kind", ["sim", "avr"])
def test_a_frame_the_device_drops_advances_no_time_and_each_sample_still_answers_its_command(kind: str) -> None:
    """Frames the device drops (a COMMAND of the wrong length, an unknown type, a wrong version),
    each read apart from the COMMAND after it, as a busy machine splits the host's writes: no SAMPLE
    comes for them, so every later SAMPLE still answers the COMMAND just sent."""
    if kind == "avr" and (reason := avr_skip_reason()):
        pytest.skip(reason)
    with _lockstep_device(kind, 200) as (dev, hw):

        def step(duty: int) -> tuple[int, int, int]:
            seq = hw.send_command(CommandFrame(duty, 0, 0, 1))
            s = hw.read_sample(20.0)
            assert s is not None, dev.control("status")
            return seq, s.cmd_seq_echo, s.device_time_us

        for _ in range(5):
            step(0)
        for bad in (_frame(0x03, bytes(4)), _frame(0x42, b""), _frame(0x03, bytes(6), version=9)):
            hw.send_raw(bad)
            time.sleep(0.3)  # the device reads this frame on its own
        assert hw.read_sample(0.5) is None  # nothing answers a dropped frame
        steps = [step(1000 * (i % 3)) for i in range(20)]
        # the firmware applies a COMMAND that lands late in its tick at the next (docs/protocol.md), so a
        # SAMPLE answers the COMMAND just sent or the one before; once settled, the one just sent. Had the
        # dropped frames cost a SAMPLE, each would answer the one before, one COMMAND late for good.
        assert all(echo in (seq, seq - 1) for seq, echo, _ in steps), steps
        assert all(echo == seq for seq, echo, _ in steps[-10:]), steps
        times = [t for _, _, t in steps]
        assert all(b - a == 1000 for a, b in itertools.pairwise(times))  # one 1 ms period per COMMAND
