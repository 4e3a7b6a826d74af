"""The Uno's USB-serial bridge between the host and a simulated device: batching, jitter, and the
DTR auto-reset on port open.

On an Arduino Uno the 328P's UART goes through an ATmega16U2 running Arduino-usbserial
(LUFA). Its main loop forwards UART bytes to the PC only when its Timer0 overflows (16 MHz /
256 / 256 = every 4.096 ms) or when more than 96 bytes wait (``BUFFER_NEARLY_FULL``), so at
1 kHz the host sees SAMPLEs 3-5 at a time. Host bytes reach the 16U2 in USB full-speed frames
(1 ms). Opening the port raises DTR, which (through a 100 nF capacitor) resets the 328P into
optiboot: the board is silent and its PWM pins are inputs (floating) for ~1 s, then the sketch
starts and says HELLO.

Run as a process that owns the device process: ``python -m rehab_hil.devices.usb_bridge --config
CFG [--seed N] -- DEVICE_ARGV...``. It starts the device, opens the device's pty, makes its own pty
for the host (its path is the first stdout line), relays bytes through the two ``Batcher`` queues,
and passes control lines through to the device. On every open of its pty (DTR) it resets the
device (``reboot external``), drops both directions for ``bootloader_ms`` and resets the device
again at the end, so the HELLO comes when the sketch would start. (The device's sketch runs
unconfigured, PWM 0, during that window; on a real Uno the pins float: the power stage needs a
gate pull-down.) An open is seen by polling the pty's hang-up state every <= 10 ms: a close and
reopen faster than that is not a DTR pulse here. Parameters: ``[rig.link]`` (``config.RigLinkSection``).
"""

from __future__ import annotations

import argparse
import errno
import math
import os
import random
import select
import subprocess
import sys
import termios
import time
import tty
from collections import deque
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

__all__ = ["Batcher", "LinkParams", "bridged_argv", "link_params", "main"]


@dataclass(frozen=True)
class LinkParams:
    """The link model's parameters in SI units (from ``[rig.link]``)."""

    to_host_flush_s: float = 0.004096
    to_host_flush_bytes: int = 96
    to_device_frame_s: float = 0.001
    jitter_s: float = 0.0
    auto_reset: bool = True
    bootloader_s: float = 1.0


def link_params(cfg: Any) -> tuple[bool, LinkParams]:
    """(bridge on?, parameters) from a validated plant config's ``[rig.link]`` (absent: off)."""
    link = cfg.rig.link
    if link is None:
        return False, LinkParams()
    return link.usb_bridge, LinkParams(link.to_host_flush_ms / 1e3, link.to_host_flush_bytes,
                                       link.to_device_frame_ms / 1e3, link.jitter_ms / 1e3, link.auto_reset,
                                       link.bootloader_ms / 1e3)


class Batcher:
    """One direction of the bridge: bytes wait for the next flush tick (a free-running timer of
    ``period_s`` from ``t0``) or go at once when more than ``flush_bytes`` wait; each flush is
    delivered ``0..jitter_s`` later (uniform), never out of order."""

    def __init__(self, period_s: float, flush_bytes: int, jitter_s: float = 0.0, t0: float = 0.0,
                 rng: random.Random | None = None) -> None:
        if not period_s > 0 or flush_bytes < 1 or jitter_s < 0:
            raise ValueError("period_s > 0, flush_bytes >= 1 and jitter_s >= 0 are required")
        self.period_s, self.flush_bytes, self.jitter_s, self.t0 = period_s, flush_bytes, jitter_s, t0
        self.rng = rng or random.Random(0)
        self.pending = bytearray()
        self.ready: deque[tuple[float, bytes]] = deque()
        self._last_delivery = -math.inf
        self._since = t0  # when the oldest waiting byte came in
        self.flushes = 0

    def _tick_after(self, t: float) -> float:
        """The first flush tick at or after ``t``."""
        return self.t0 + math.ceil((t - self.t0) / self.period_s - 1e-12) * self.period_s

    def _flush(self, t: float) -> None:
        if not self.pending:
            return
        at = max(t + (self.rng.uniform(0.0, self.jitter_s) if self.jitter_s else 0.0), self._last_delivery)
        self._last_delivery = at
        self.ready.append((at, bytes(self.pending)))
        self.pending.clear()
        self.flushes += 1

    def push(self, now: float, data: bytes) -> None:
        """Bytes entering the bridge at ``now`` (calls come in time order)."""
        self._tick(now)
        if not self.pending:
            self._since = now
        self.pending += data
        if len(self.pending) > self.flush_bytes:
            self._flush(now)

    def _tick(self, now: float) -> None:
        """The flush tick that fired since the waiting bytes came in, if it has."""
        if self.pending and (tick := self._tick_after(self._since)) <= now:
            self._flush(tick)

    def due(self, now: float) -> bytes:
        """Everything whose delivery time has come."""
        self._tick(now)
        out = bytearray()
        while self.ready and self.ready[0][0] <= now:
            out += self.ready.popleft()[1]
        return bytes(out)

    def next_time(self) -> float | None:
        """When something next happens (a flush tick with bytes waiting, or a delivery), or None."""
        times = []
        if self.pending:
            times.append(self._tick_after(self._since))
        if self.ready:
            times.append(self.ready[0][0])
        return min(times) if times else None

    def clear(self) -> None:
        """Forget everything in flight (the board reset: the 16U2's buffers are dropped too)."""
        self.pending.clear()
        self.ready.clear()


def bridged_argv(config_path: str, device_argv: list[str], seed: int = 0, native_bootloader: bool = False) -> list[str]:
    """The argv that runs ``device_argv`` behind the bridge. ``native_bootloader``: the device runs
    the real bootloader (the firmware in simavr with optiboot): DTR is one external reset, no
    emulated silence."""
    return [sys.executable, "-c", "import sys; from rehab_hil.devices.usb_bridge import main; sys.exit(main())",
            "--config", str(config_path), "--seed", str(seed), *(["--native-bootloader"] if native_bootloader else []),
            "--", *device_argv]


class _Relay:
    """The bridge process: the device child, the host pty, the two batchers and the control pass-through."""

    def __init__(self, params: LinkParams, device_argv: list[str], seed: int, native_bootloader: bool = False) -> None:
        self.p, self.native_bootloader = params, native_bootloader
        self.child = subprocess.Popen(device_argv, stdin=subprocess.PIPE, stdout=subprocess.PIPE, bufsize=0)
        self._child_out = b""
        dev_path = self._child_line(120.0)
        if not dev_path.startswith("/dev/"):
            raise RuntimeError(f"device printed {dev_path!r} instead of its pty path")
        self.dev = os.open(dev_path, os.O_RDWR | os.O_NOCTTY | os.O_NONBLOCK)
        tty.setraw(self.dev, termios.TCSANOW)
        self.master, slave = os.openpty()
        tty.setraw(slave, termios.TCSANOW)
        tty.setraw(self.master, termios.TCSANOW)
        self.path = os.ttyname(slave)
        os.close(slave)  # so POLLHUP on the master says whether the host has the port open
        os.set_blocking(self.master, False)
        now = time.perf_counter()
        rng = random.Random(seed)
        self.up = Batcher(params.to_host_flush_s, params.to_host_flush_bytes, params.jitter_s, now, rng)
        self.down = Batcher(params.to_device_frame_s, 1 << 30, params.jitter_s, now, rng)
        self.host_open = False
        self.resetting = 0  # resets sent to the device and not yet acknowledged
        self.silent_until = 0.0
        self.rebooting = False
        self.internal_replies = 0  # replies to our own reboot commands, not forwarded
        self.resets = 0

    def _child_line(self, timeout: float) -> str:
        assert self.child.stdout is not None
        fd = self.child.stdout.fileno()
        deadline = time.monotonic() + timeout
        while b"\n" not in self._child_out:
            left = deadline - time.monotonic()
            if left <= 0 or not select.select([fd], [], [], left)[0]:
                raise RuntimeError("the device process did not start")
            chunk = os.read(fd, 4096)
            if not chunk:
                raise RuntimeError(f"the device process exited ({self.child.wait()})")
            self._child_out += chunk
        line, self._child_out = self._child_out.split(b"\n", 1)
        return line.decode(errors="replace").strip()

    def _to_child(self, line: str) -> None:
        assert self.child.stdin is not None
        self.child.stdin.write(line.encode() + b"\n")

    def _reset_device(self, now: float) -> None:
        """DTR went up: the 328P resets into the bootloader; silent until it hands over."""
        self._to_child("reboot external")
        self.internal_replies += 1
        # bytes the device sent before the reset took effect (a power-up HELLO still in its pty)
        # are dropped until the device acknowledges the reset: a real 16U2 never delivers them,
        # since the host had not opened the port (measured: under load a stale HELLO reached the
        # host before optiboot had run, 2 runs in 6)
        self.resetting += 1
        self.up.clear()
        self.down.clear()
        self.resets += 1
        if not self.native_bootloader:  # the device has none: emulate its silence, then the sketch's start
            self.silent_until = now + self.p.bootloader_s
            self.rebooting = True

    def _host_is_open(self) -> bool:
        p = select.poll()
        p.register(self.master, select.POLLIN)
        return not any(ev & select.POLLHUP for _, ev in p.poll(0))

    def run(self) -> None:
        """Relay bytes between the host's pty and the device's, delayed as the USB chip delays them,
        and the control channel between stdin/stdout and the device process, until either ends."""
        assert self.child.stdout is not None
        cfd = self.child.stdout.fileno()
        pending = b""
        while self.child.poll() is None:
            now = time.perf_counter()
            is_open = self._follow_host(now)
            readable = self._wait_readable(cfd, is_open, now)
            now = time.perf_counter()
            self._read_links(readable, now)
            if cfd in readable:
                chunk = os.read(cfd, 4096)
                if not chunk:
                    break
                self._child_out += chunk
                self._relay_child_lines()
            if 0 in readable:
                chunk = os.read(0, 4096)
                if not chunk:
                    break
                pending += chunk
                while b"\n" in pending:
                    line, pending = pending.split(b"\n", 1)
                    self._to_child(line.decode(errors="replace"))
            out = self.down.due(now)
            if out:
                _write(self.dev, out)
            out = self.up.due(now)
            if out and self.host_open:
                _write(self.master, out)
        self.close()

    def _follow_host(self, now: float) -> bool:
        """Is the host's port open? Opening it resets the device (DTR, with ``auto_reset``); the
        emulated bootloader's silence ends in the sketch's start."""
        is_open = self._host_is_open()
        if is_open and not self.host_open and self.p.auto_reset:
            self._reset_device(now)
        self.host_open = is_open
        if self.rebooting and now >= self.silent_until:  # optiboot times out: the sketch starts
            self.rebooting = False
            self._to_child("reboot external")
            self.internal_replies += 1
            self.up.clear()
        return is_open

    def _wait_readable(self, cfd: int, is_open: bool, now: float) -> list[int]:
        """The descriptors readable within the time to the next due delivery (at most 10 ms)."""
        times = [t for t in (self.up.next_time(), self.down.next_time()) if t is not None]
        if self.rebooting:
            times.append(self.silent_until)
        wait = min(times) - now if times else (0.01 if is_open else 0.002)
        fds = [self.dev, cfd, 0] + ([self.master] if is_open else [])
        readable, _, _ = select.select(fds, [], [], max(0.0, min(wait, 0.01)))
        return readable

    def _read_links(self, readable: list[int], now: float) -> None:
        """Queue what the host and the device wrote (nothing while the device reboots or resets)."""
        if self.master in readable:
            data = _read(self.master)
            if data and not self.rebooting:
                self.down.push(now, data)
        if self.dev in readable:
            data = _read(self.dev)
            if data and not self.rebooting and not self.resetting:
                self.up.push(now, data)

    def _relay_child_lines(self) -> None:
        """The device process's whole output lines: replies to the bridge's own requests are consumed
        (a reset's reply flushes what the device sent before it), the others go to stdout."""
        while b"\n" in self._child_out:
            line, self._child_out = self._child_out.split(b"\n", 1)
            if self.internal_replies:
                self.internal_replies -= 1
                if self.resetting:
                    self.resetting -= 1
                    # what the device sent before the reset: every byte written before this reply,
                    # also those still in the pty's flip buffer (a read here missed them under load,
                    # and a stale power-up HELLO reached the host before optiboot had run)
                    termios.tcflush(self.dev, termios.TCIFLUSH)
                    self.up.clear()
            else:
                sys.stdout.buffer.write(line + b"\n")
                sys.stdout.flush()

    def close(self) -> None:
        if self.child.poll() is None:
            try:
                if self.child.stdin is not None:
                    self.child.stdin.close()
                self.child.wait(timeout=3)
            except (subprocess.TimeoutExpired, OSError):
                self.child.kill()
                self.child.wait()
        for fd in (self.dev, self.master):
            try:
                os.close(fd)
            except OSError:
                pass


def _read(fd: int) -> bytes:
    try:
        return os.read(fd, 65536)
    except (BlockingIOError, InterruptedError):
        return b""
    except OSError as e:
        if e.errno == errno.EIO:  # the other side is not open
            return b""
        raise


def _write(fd: int, data: bytes) -> None:
    """Non-blocking; bytes nobody reads are lost (as a full USB buffer on the PC would lose them)."""
    try:
        os.write(fd, data)
    except (BlockingIOError, InterruptedError):
        pass
    except OSError as e:
        if e.errno not in (errno.EIO, errno.EAGAIN):
            raise


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of the bridge process (see the module docstring)."""
    p = argparse.ArgumentParser(prog="python -m rehab_hil.devices.usb_bridge",
                                description="The Uno's 16U2 USB bridge between a host and a simulated device.")
    p.add_argument("--config", required=True, help="plant config: its [rig.link] table")
    p.add_argument("--seed", type=int, default=0, help="seed of the jitter")
    p.add_argument("--native-bootloader", action="store_true",
                   help="the device runs its own bootloader (simavr + optiboot): DTR is one reset, nothing emulated")
    p.add_argument("device_argv", nargs=argparse.REMAINDER, help="-- then the device's command line")
    args = p.parse_args(argv)
    device_argv = args.device_argv[1:] if args.device_argv[:1] == ["--"] else args.device_argv
    from rehab_hil.config import ConfigError
    from rehab_hil.loading import load_config

    try:
        _, params = link_params(load_config(args.config))
        if not device_argv:
            raise ValueError("no device command line after --")
    except (ConfigError, ValueError) as e:
        print(f"usb bridge: error: {e}", file=sys.stderr)
        return 2
    relay = _Relay(params, device_argv, args.seed, args.native_bootloader)
    print(relay.path, flush=True)
    try:
        relay.run()
    except KeyboardInterrupt:
        relay.close()
    return 0


if __name__ == "__main__":
    sys.exit(main())
