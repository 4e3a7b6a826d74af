"""The firmware tests run the real sketch (firmware/build/rehab_fw.elf) in simavr through the
C harness (sim_devices/build/avr_harness), each test with its own harness process and pty.

``make firmware harness`` builds both (``make test`` does it first); without them the tests
are skipped with the reason."""

from __future__ import annotations

import os
import select
import subprocess
import time
from collections.abc import Iterator
from pathlib import Path

import pytest

from rehab_hil.hardware import SerialHardware
from rehab_hil.protocol import DUTY_FULL, Configure, FrameDecoder, Hello, Message

ROOT = Path(__file__).resolve().parents[2]
HARNESS = ROOT / "sim_devices" / "build" / "avr_harness"
ELF = ROOT / "firmware" / "build" / "rehab_fw.elf"
WIDE = 1 << 30


def config(**kw: int) -> Configure:
    """A wide-open configuration with ``kw`` overriding single fields."""
    base = dict(sample_rate_hz=1000, watchdog_ms=500, max_duty=DUTY_FULL, max_heating_ms=60_000,
                force_limit_counts=1023, enc_min=-WIDE, enc_max=WIDE, flags=0)
    base.update(kw)
    return Configure(**base)


class Hardware(SerialHardware):
    """SerialHardware with request timeouts of at least 5 s: on a loaded CI machine the simulated
    AVR can run at a fraction of real time (device-time assertions are unaffected)."""

    def _request(self, msg: Message, timeout: float) -> int:
        return super()._request(msg, max(timeout, 5.0))


class Harness:
    """One avr_harness process (no plant: the test drives the encoder, ADC and e-stop pin)."""

    def __init__(self, elf: Path = ELF, *args: str) -> None:
        self.proc = subprocess.Popen([str(HARNESS), *args, str(elf)], stdin=subprocess.PIPE,
                                     stdout=subprocess.PIPE, stderr=subprocess.PIPE, bufsize=0)
        self._buf = b""
        try:
            self.port = self.line(10.0)
        except BaseException:
            self.close()
            raise

    def line(self, timeout: float = 5.0) -> str:
        assert self.proc.stdout is not None
        fd = self.proc.stdout.fileno()
        deadline = time.monotonic() + timeout
        while b"\n" not in self._buf:
            left = deadline - time.monotonic()
            if left <= 0 or not select.select([fd], [], [], left)[0]:
                raise TimeoutError("no reply from the harness")
            chunk = os.read(fd, 4096)
            if not chunk:
                raise RuntimeError(f"harness exited: {self.stderr()}")
            self._buf += chunk
        text, self._buf = self._buf.split(b"\n", 1)
        return text.decode()

    def send(self, line: str) -> None:
        assert self.proc.stdin is not None
        self.proc.stdin.write(line.encode() + b"\n")

    def state(self) -> dict[str, int]:
        """The PWM/encoder state the harness reads from the AVR's registers now."""
        self.send("S")
        f = self.line().split()
        assert f[0] == "T", f
        keys = ("sim_us", "duty0", "duty1", "dir", "encoder", "resets", "tx_dropped", "rx_dropped", "rx_frames_hit")
        return dict(zip(keys, map(int, f[1:]), strict=True))

    def stderr(self) -> str:
        if self.proc.poll() is None or self.proc.stderr is None:
            return ""
        return self.proc.stderr.read().decode(errors="replace")[-2000:]

    def close(self) -> None:
        if self.proc.poll() is None:
            try:
                assert self.proc.stdin is not None
                self.proc.stdin.close()  # EOF ends the harness
                self.proc.wait(timeout=3)
            except (subprocess.TimeoutExpired, OSError):
                self.proc.kill()
                self.proc.wait()
        for f in (self.proc.stdout, self.proc.stderr):
            if f is not None:
                f.close()


def unsolicited_hello(hw: SerialHardware, timeout_s: float = 5.0) -> tuple[Hello, int]:
    """The next HELLO on the raw link (a boot's: the host did not ask for it), and its seq. The raw
    reads take bytes from the middle of ``hw``'s stream, so its decoder starts afresh after them
    (left holding part of a frame, it merged it with the next ACK and lost that ACK)."""
    dec, ser = FrameDecoder(), hw._require()
    deadline = time.monotonic() + timeout_s
    try:
        while time.monotonic() < deadline:
            for f in dec.feed(ser.read(4096)):
                if isinstance(f.msg, Hello):
                    return f.msg, f.seq
            time.sleep(0.002)
        raise AssertionError("no HELLO")
    finally:
        hw.flush_input()


def _missing() -> str | None:
    for p in (HARNESS, ELF):
        if not p.exists():
            return f"{p.relative_to(ROOT)} not built: run `make firmware harness`"
    return None


@pytest.fixture
def harness() -> Iterator[Harness]:
    reason = _missing()
    if reason:
        pytest.skip(reason)
    h = Harness()
    try:
        yield h
    finally:
        h.close()


@pytest.fixture
def rig(harness: Harness) -> Iterator[tuple[Harness, SerialHardware]]:
    """The harness plus a connected host link, configured wide open."""
    hw = Hardware(harness.port)
    try:
        hw.connect(timeout=10.0)
        hw.configure(config())
        yield harness, hw
    finally:
        hw.close()
