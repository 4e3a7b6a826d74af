"""The Uno's USB bridge model (devices/usb_bridge.py): the 16U2's batching as a pure queue, and
both simulated devices behind it on a real pty: DTR auto-reset on open (the Python device: silent
for the emulated bootloader, then a HELLO with reset cause external; the firmware in simavr: the
real optiboot loaded with it, which clears the cause), PWM off after the reset, samples arriving in
bursts."""

from __future__ import annotations

import itertools
import random
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

from rehab_hil.devices.usb_bridge import Batcher
from rehab_hil.hardware import SerialHardware
from rehab_hil.protocol import DUTY_FULL, Configure, ResetCause, Sample, Status, encode_frame

from .conftest import CONFIG, avr_skip_reason

BOOT_MS = 300.0  # shorter than optiboot's ~1 s: keeps the tests short, the behaviour is the same
SAMPLE_FRAME_BYTES = len(encode_frame(Sample(0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0), 1))  # 37 B


def test_bytes_wait_for_the_next_4096_us_tick() -> None:
    b = Batcher(0.004096, 96, t0=0.0)
    b.push(0.0005, b"a" * 37)
    assert b.due(0.004) == b"" and b.next_time() == pytest.approx(0.004096)
    b.push(0.0015, b"b" * 37)
    assert b.due(0.0041) == b"a" * 37 + b"b" * 37  # one USB packet at the tick
    b.push(0.0050, b"c")
    assert b.next_time() == pytest.approx(0.008192)


def test_more_than_96_bytes_go_at_once() -> None:
    b = Batcher(0.004096, 96, t0=0.0)
    b.push(0.0001, b"x" * 37)
    b.push(0.0011, b"x" * 37)
    assert b.due(0.0021) == b""
    b.push(0.0021, b"x" * 37)  # 111 B > 96: flushed on arrival
    assert b.due(0.0021) == b"x" * 111


def test_jitter_delays_flushes_but_never_reorders_them() -> None:
    b = Batcher(0.001, 1000, jitter_s=0.003, t0=0.0, rng=random.Random(4))
    for k in range(200):  # two bytes between two 1 ms ticks
        b.push(k * 0.0005 + 0.0002, bytes([k % 251]))
    out = b.due(1.0)
    assert out == bytes(k % 251 for k in range(200))
    assert b.flushes == 100


def bridged_config(tmp_path: Path) -> Path:
    text = CONFIG.read_text()
    text = text.replace("usb_bridge = false", "usb_bridge = true").replace("bootloader_ms = 1000.0",
                                                                          f"bootloader_ms = {BOOT_MS}")
    assert "usb_bridge = true" in text
    path = tmp_path / "bridged.toml"
    path.write_text(text)
    return path


def resets(dev: Any) -> int:
    """The firmware-in-simavr's count of AVR resets (its status line)."""
    return int(dict(kv.split("=") for kv in dev.control("status").split()[1:] if "=" in kv)["resets"])


@pytest.fixture(params=["sim", "avr"])
def bridged(request: pytest.FixtureRequest, tmp_path: Path) -> Iterator[Any]:
    if request.param == "avr" and (reason := avr_skip_reason()):
        pytest.skip(reason)
    from rehab_hil.devices import spawn_device

    dev = spawn_device(request.param, bridged_config(tmp_path), clock="realtime")
    try:
        yield dev
    finally:
        dev.close()


@pytest.mark.slow
@pytest.mark.timeout(120)
@pytest.mark.xdist_group("sim_devices")
def test_opening_the_port_resets_the_device_silent_for_the_bootloader_then_hello_and_samples_in_bursts(
        bridged: Any) -> None:
    wide = Configure(1000, 1000, DUTY_FULL, 60_000, 1023, -(1 << 30), 1 << 30, 0)
    avr = bridged.kind == "avr"  # the real optiboot in simavr; the Python device's bootloader is emulated
    hw = SerialHardware(bridged.port, write_timeout_s=2.0)
    t_open = time.perf_counter()
    try:
        hello = hw.connect(timeout=15.0)
        if avr:  # optiboot ran (DTR reset, then its own watchdog reset); it clears MCUSR: cause unknown
            assert resets(bridged) >= 2 and hello.reset_cause == 0
        else:
            assert time.perf_counter() - t_open >= BOOT_MS / 1e3 * 0.95  # nothing answers during the bootloader
            assert hello.reset_cause & ResetCause.EXTERNAL
        hw.configure(wide, timeout=5.0)
        hw.write_command(0.3)
        arrivals, samples = [], []
        while len(samples) < 300:
            s = hw.read_sample(timeout=2.0)
            assert s is not None
            samples.append(s)
            arrivals.append(hw.last_sample_time)
            if len(samples) % 4 == 0:
                hw.write_command(0.3)  # keep the watchdog fed
        assert any(s.duty0 > 0 for s in samples)
        # bursts: the bridge writes to the host only at its 4.096 ms ticks or when more than 96 bytes
        # wait, so the samples arrive in no more groups (arrivals closer than 0.3 ms: one read) than
        # ticks passed plus overflow flushes (each > 96 B of 37 B SAMPLE frames), plus the first and
        # a backlog or two written late. Without a bridge at 1 kHz on an idle machine every sample is
        # a group of its own: 300 groups against a bound of ~190. (The former check, "most gaps under
        # 0.3 ms", assumed a device keeping real time: beside two busy loops the firmware in simavr
        # ran slower, one sample per tick, and 45-97 of 299 gaps were short.)
        gaps = [b - a for a, b in itertools.pairwise(arrivals)]
        groups = 1 + sum(g >= 0.0003 for g in gaps)
        ticks = (arrivals[-1] - arrivals[0]) / 0.004096
        print(f"{bridged.kind}: {len(samples)} samples in {groups} arrival groups over {ticks:.0f} bridge ticks")
        assert groups <= ticks + len(samples) * SAMPLE_FRAME_BYTES / 97 + 3, (groups, ticks, len(samples))
        # a reopen is a DTR pulse: the board resets, the drive it had is gone. The bridge polls the
        # port's hang-up once per pass of its loop (every <= 10 ms when it runs): a close and reopen
        # between two polls is not seen. A control line's round trip passes through that loop, so
        # once its reply is back the bridge has polled the closed port (a 0.1 s sleep was not enough
        # beside two busy loops: no reset, sample_index 378 with the drive still on after the reopen).
        hw.close()
        bridged.control("status")
        before = resets(bridged) if avr else 0
        hw = SerialHardware(bridged.port, write_timeout_s=2.0)
        hello = hw.connect(timeout=15.0)
        assert resets(bridged) > before if avr else hello.reset_cause & ResetCause.EXTERNAL
        hw.configure(wide, timeout=5.0)
        s = hw.read_sample(timeout=2.0)
        assert s is not None and s.sample_index < 50 and s.duty0 == 0 and not s.status & Status.PWM_ENABLED
    finally:
        hw.close()
