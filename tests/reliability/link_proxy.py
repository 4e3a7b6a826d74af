"""A serial link with faults: a pty man-in-the-middle between the host and a device's pty.

Why: the simulated devices can drop, corrupt, delay or truncate whole frames they send, but a real
cable also loses single bytes, flips single bits in both directions and gets unplugged while the
device keeps running. ``LinkProxy`` opens the device's pty like a host would, offers the host a new
pty of its own, and moves bytes between the two in a process of its own, injecting those faults on
the way.

It also *taps* the device's output before any fault is injected (``DeviceTap``): every SAMPLE the
device sent, in device time, whether the host got it or not. That is how the tests see the
device's PWM while the link is down, and how they check the safety invariant: the PWM is never on
more than ``watchdog_ms`` of device time after the last COMMAND the device applied. (A loaded
machine that starves the proxy can still lose the device's output before the tap: its pty, or the
USB-bridge model's, fills and drops bytes. The tap says where: gaps in sample_index, bad frames.)
"""

from __future__ import annotations

import errno
import multiprocessing
import os
import random
import select
import threading
import time
import tty
from collections import Counter, deque
from dataclasses import dataclass, field
from multiprocessing.connection import Connection
from typing import Any

from rehab_hil.protocol import CommandFrame, FaultReport, FrameDecoder, Hello, Sample

__all__ = ["DeviceTap", "Direction", "LinkProxy"]

OUT_CAP = 4096  # bytes queued per direction, like a tty buffer; beyond, new bytes are lost (overrun)


class DeviceTap:
    """Decodes one direction of the link as it really is, and checks the device's PWM as it goes.

    Online (flat memory, so the soak benchmark can use it for hours): samples seen, PWM-on while a
    fault is latched (a safety violation), and the longest PWM-on time since the last command the
    device applied, in device time. ``keep`` keeps every SAMPLE for the tests."""

    def __init__(self, keep: bool = True) -> None:
        self.decoder = FrameDecoder()
        self.keep = keep
        self.samples: list[Sample] = []
        self.hellos = 0
        self.fault_reports: list[FaultReport] = []
        self.commands = 0
        self.n_samples = 0
        self.violations = 0  # samples with PWM on while a fault is latched
        self.worst_on_since_command_us = 0  # longest device time PWM stayed on after the last applied COMMAND
        self.pwm_off_after_command_us: list[int] = []  # per PWM-on -> off transition without a fresh command
        # a transition the tap saw only across a gap in sample_index (the device's output lost before the
        # tap: its pty full while a loaded machine starved the proxy): the PWM went off somewhere in
        # between, so only (last seen on, first seen off) since the command is known, not the moment
        self.pwm_off_unresolved_us: list[tuple[int, int]] = []
        self._last_on_since = 0
        self._last_index: int | None = None
        self.recent: deque[tuple[int, int, bool]] = deque(maxlen=20_000)  # (boot, device_time_us, pwm on)
        self.boots = 0
        self._echo: int | None = None
        self._t_echo = 0
        self._was_on = False
        self.last: Sample | None = None
        # The firmware reports a new trip in a FAULT frame just before the first SAMPLE that shows it.
        # Trips a SAMPLE showed with no such report: (bits, whether the device's output since the
        # previous SAMPLE reached the tap whole). Only a loss before the tap may hide a report.
        self.unreported_trips: list[tuple[int, bool]] = []
        self._latched = 0  # fault bits in the previous SAMPLE
        self._reported = 0  # bits in FAULT frames since the previous SAMPLE
        self._damaged = False  # a bad frame since the previous SAMPLE

    def feed(self, data: bytes) -> None:
        bad = self.decoder.bad_total
        frames = self.decoder.feed(data)
        # the decoder does not say where in the chunk a bad frame was: every SAMPLE in a damaged
        # chunk counts as after the damage (a report is excused more often, never demanded wrongly)
        self._damaged |= self.decoder.bad_total != bad
        for frame in frames:
            msg = frame.msg
            if isinstance(msg, Sample):
                self._sample(msg)
            elif isinstance(msg, Hello):
                self.hellos += 1
                self.boots += 1
                self._echo, self._was_on, self._last_index = None, False, None  # a reboot restarts device time
                self._latched = 0
            elif isinstance(msg, FaultReport):
                self.fault_reports.append(msg)
                self._reported |= msg.faults
            elif isinstance(msg, CommandFrame):
                self.commands += 1

    def pwm_off_after(self, device_time_us: int) -> int | None:
        """Device time from ``device_time_us`` (same boot) to the first tapped SAMPLE with PWM off
        (None if none was seen yet): how long PWM stayed on after, e.g., the host lost the link."""
        if not self.recent:
            return None
        boot = self.recent[-1][0]
        for b, t, on in self.recent:
            if b == boot and t >= device_time_us and not on:
                return t - device_time_us
        return None

    def _sample(self, s: Sample) -> None:
        self.n_samples += 1
        self.last = s
        unreported = s.faults & ~self._latched & ~self._reported
        if unreported:
            whole = not self._damaged and self._last_index is not None and s.sample_index == self._last_index + 1
            self.unreported_trips.append((unreported, whole))
        self._latched, self._reported, self._damaged = s.faults, 0, False
        if self.keep:
            self.samples.append(s)
        if self._echo is None or s.cmd_seq_echo != self._echo:
            # a new COMMAND was applied at or before this sample: the watchdog was fed no later than now
            self._echo, self._t_echo = s.cmd_seq_echo, s.device_time_us
        on = bool(s.duty0 or s.duty1)
        self.recent.append((self.boots, s.device_time_us, on))
        since = (s.device_time_us - self._t_echo) & 0xFFFFFFFF
        if on:
            self.worst_on_since_command_us = max(self.worst_on_since_command_us, since)
            if s.faults:
                self.violations += 1
        elif self._was_on and since > 0:
            if self._last_index is not None and s.sample_index == self._last_index + 1:
                self.pwm_off_after_command_us.append(since)
            else:
                self.pwm_off_unresolved_us.append((self._last_on_since, since))
        if on:
            self._last_on_since = since
        self._was_on = on
        self._last_index = s.sample_index


@dataclass
class Direction:
    """Fault knobs of one direction of the link (probabilities per byte)."""

    drop_p: float = 0.0
    flip_p: float = 0.0
    delay_s: float = 0.0
    stall_until: float = 0.0  # perf_counter: swallow everything until then
    garbage: int = 0  # random bytes to inject before the next data
    truncate: int = 0  # frames to cut in half (the rest of the frame up to its delimiter is lost)
    injected: Counter[str] = field(default_factory=Counter)  # what was done, by kind
    _cutting: bool = False


class _Engine:
    """The proxy itself, run in the proxy's own process (``LinkProxy`` is its remote control)."""

    def __init__(self, device_port: str, seed: int = 0, keep_samples: bool = True) -> None:
        self.rng = random.Random(seed)
        self.dev = os.open(device_port, os.O_RDWR | os.O_NOCTTY | os.O_NONBLOCK)
        tty.setraw(self.dev)
        self.master, slave = os.openpty()
        tty.setraw(self.master)
        tty.setraw(slave)
        self.port = os.ttyname(slave)
        os.close(slave)  # the host opens it by path; a pty master reads EIO until then, which we tolerate
        os.set_blocking(self.master, False)
        self.down, self.up = Direction(), Direction()
        self.device_tap = DeviceTap(keep=keep_samples)
        self.host_tap = DeviceTap(keep=False)
        self.bytes_down = self.bytes_up = 0
        self.unplugged = False
        self._held: list[tuple[float, bool, bytes]] = []  # delayed chunks: (due, downward, data)
        self._out: dict[bool, bytearray] = {True: bytearray(), False: bytearray()}  # queued for the host / device
        self._stop = False

    # ---- knobs --------------------------------------------------------------------------------

    def unplug(self) -> None:
        if not self.unplugged:
            self.unplugged = True
            os.close(self.master)

    # ---- thread -------------------------------------------------------------------------------

    def serve(self, conn: Connection) -> None:
        """Forward until told to close; control requests arrive on ``conn`` (see ``LinkProxy``)."""
        ctl = conn.fileno()
        while not self._stop:
            fds = [self.dev, ctl] + ([] if self.unplugged else [self.master])
            readable, _, _ = select.select(fds, [], [], 0.001)
            if self.dev in readable:
                data = self._read(self.dev)
                if data:
                    self.device_tap.feed(data)
                    self.bytes_down += len(data)
                    self._pass(data, self.down, downward=True)
            if not self.unplugged and self.master in readable:
                data = self._read(self.master)
                if data:
                    self.bytes_up += len(data)
                    self._pass(data, self.up, downward=False)
            if ctl in readable:
                try:
                    request = conn.recv()
                except EOFError:  # the parent is gone
                    break
                try:
                    conn.send(("ok", self._control(*request)))
                except Exception as e:  # a bad request: reported to the caller, the link keeps going
                    conn.send(("error", repr(e)))
            self._release()
            self._flush(True)
            self._flush(False)
        self.unplug()
        os.close(self.dev)

    def _control(self, op: str, *args: Any) -> Any:
        if op == "set":
            name, key, value = args
            if key not in _KNOBS:
                raise AttributeError(f"no knob {key!r}")
            setattr(getattr(self, name), key, value)
            return None
        if op == "get":
            name, key = args
            return getattr(getattr(self, name), key)
        if op == "stall":
            name, seconds = args
            getattr(self, name).stall_until = time.perf_counter() + seconds
            return None
        if op == "unplug":
            self.unplug()
            return None
        if op == "tap":
            return getattr(self, args[0])
        if op == "describe":
            return self.describe()
        if op == "close":
            self._stop = True
            return None
        raise ValueError(f"unknown request {op!r}")

    @staticmethod
    def _read(fd: int) -> bytes:
        try:
            return os.read(fd, 4096)
        except (BlockingIOError, InterruptedError):
            return b""
        except OSError as e:
            if e.errno in (errno.EIO, errno.EBADF):  # the other side is not open (yet / any more)
                time.sleep(0.001)
                return b""
            raise

    def _pass(self, data: bytes, d: Direction, downward: bool) -> None:
        now = time.perf_counter()
        if now < d.stall_until:
            d.injected["stalled_bytes"] += len(data)
            return
        room = OUT_CAP - len(self._out[downward]) - len(data)
        # fast path: no byte faults; and a chunk the overrun will lose whole (a reader starved by a busy
        # machine) takes none of the faults still to come with it, so they reach the reader later
        if room < 0 or not (d.garbage or d.truncate or d._cutting or d.drop_p or d.flip_p):
            out = bytearray(data)
        else:
            out = self._damage(data, d, room)
        if d.delay_s > 0:
            self._held.append((now + d.delay_s, downward, bytes(out)))
        else:
            self._deliver(bytes(out), downward)

    def _damage(self, data: bytes, d: Direction, room: int) -> bytearray:
        """``data`` with this direction's byte faults. A garbage burst goes in only where the queue
        has ``room`` for it whole: one the overrun would swallow waits for a later chunk, so the
        fault reaches the reader, as a test of it needs."""
        out = bytearray()
        if d.garbage and d.garbage <= room:
            out += bytes(self.rng.randrange(256) for _ in range(d.garbage))
            d.injected["garbage_bytes"] += d.garbage
            d.garbage = 0
        for b in data:
            if d._cutting:  # inside a frame being truncated: lose bytes up to its delimiter
                if b == 0:
                    d._cutting = False
                    out.append(0)
                continue
            if d.truncate and b != 0 and self.rng.random() < 0.05:
                d.truncate -= 1
                d._cutting = True
                d.injected["truncated_frames"] += 1
                continue
            if d.drop_p and self.rng.random() < d.drop_p:
                d.injected["dropped_bytes"] += 1
                continue
            if d.flip_p and self.rng.random() < d.flip_p:
                b ^= 1 << self.rng.randrange(8)
                d.injected["flipped_bits"] += 1
            out.append(b)
        return out

    def _release(self) -> None:
        if not self._held:
            return
        now = time.perf_counter()
        while self._held and self._held[0][0] <= now:
            _, downward, data = self._held.pop(0)
            self._deliver(data, downward)

    def _deliver(self, data: bytes, downward: bool) -> None:
        """Queue bytes for one side; never blocks (a blocked proxy would starve the other direction).
        Beyond ``OUT_CAP`` queued bytes the reader is not keeping up: the new bytes are lost and
        counted, as a UART overrun would lose them."""
        if not downward:
            self.host_tap.feed(data)
        out = self._out[downward]
        if len(out) + len(data) > OUT_CAP:
            (self.down if downward else self.up).injected["overrun_bytes"] += len(data)
            return
        out += data
        self._flush(downward)

    def _flush(self, downward: bool) -> None:
        out = self._out[downward]
        if not out:
            return
        if downward and self.unplugged:
            out.clear()
            return
        try:
            n = os.write(self.master if downward else self.dev, out)
        except BlockingIOError:
            return
        except OSError as e:
            if e.errno in (errno.EIO, errno.EBADF):  # nobody on the other side: the bytes are lost
                out.clear()
                return
            raise
        del out[:n]

    def describe(self) -> str:
        """One line of counters (for assertion messages)."""
        return (f"proxy: down {self.bytes_down} B {dict(self.down.injected)} queued {len(self._out[True])} B, "
                f"up {self.bytes_up} B {dict(self.up.injected)} queued {len(self._out[False])} B, "
                f"device frames {self.device_tap.decoder.frames} bad {dict(self.device_tap.decoder.bad)}, "
                f"host frames {self.host_tap.decoder.frames} bad {dict(self.host_tap.decoder.bad)}, "
                f"unplugged {self.unplugged}")



_KNOBS = ("drop_p", "flip_p", "delay_s", "garbage", "truncate")


def _serve(device_port: str, seed: int, keep_samples: bool, conn: Connection) -> None:
    """Body of the proxy process: open both ptys, report the host's path, forward until closed."""
    try:
        engine = _Engine(device_port, seed, keep_samples)
    except BaseException as e:
        conn.send(("error", repr(e)))
        return
    conn.send(("ok", engine.port))
    engine.serve(conn)


class _Knobs:
    """One direction's knobs in the proxy process: attribute writes and reads go over the pipe."""

    def __init__(self, proxy: LinkProxy, name: str) -> None:
        object.__setattr__(self, "_proxy", proxy)
        object.__setattr__(self, "name", name)

    def __setattr__(self, key: str, value: Any) -> None:
        self._proxy._call("set", self.name, key, value)

    def __getattr__(self, key: str) -> Any:
        return self._proxy._call("get", self.name, key)


class LinkProxy:
    """Forward bytes between a device pty and a new host-facing pty, with faults; a context manager.

    The forwarding runs in a process of its own (forked), like the kernel and the USB adapter of a
    real link: in the host's process it would compete for the GIL with the loop under test and
    stall the link whenever the host stalls. ``port`` is the path the host opens. ``down``
    (device -> host) and ``up`` (host -> device) hold the knobs (``drop_p``, ``flip_p``,
    ``delay_s``, ``garbage``, ``truncate``; ``injected`` counts what was done); ``device_tap`` is a
    snapshot of the device's output before faults, ``host_tap`` of the host's output after them
    (what the device really received). ``unplug()`` closes the host's side (the host reads EIO, like
    a pulled USB cable) and stops forwarding; the device keeps running and stays tapped."""

    def __init__(self, device_port: str, seed: int = 0, keep_samples: bool = True) -> None:
        ctx = multiprocessing.get_context("fork")  # no re-import: the proxy starts in milliseconds
        self._conn, child = ctx.Pipe()
        self._lock = threading.Lock()
        self._proc = ctx.Process(target=_serve, args=(device_port, seed, keep_samples, child),
                                 name="link-proxy", daemon=True)
        self._proc.start()
        child.close()
        self._closed = False
        if not self._conn.poll(30):
            self.close()
            raise RuntimeError("link proxy did not start within 30 s")
        status, value = self._conn.recv()
        if status != "ok":
            self.close()
            raise RuntimeError(f"link proxy failed to start: {value}")
        self.port: str = value
        self.down = _Knobs(self, "down")
        self.up = _Knobs(self, "up")

    def _call(self, *request: Any) -> Any:
        with self._lock:
            self._conn.send(request)
            if not self._conn.poll(60):  # a cap: beside two busy loops the proxy process took over 10 s to answer
                raise RuntimeError(f"link proxy did not answer {request[0]!r}")
            status, value = self._conn.recv()
        if status != "ok":
            raise RuntimeError(f"link proxy: {request!r}: {value}")
        return value

    def stall(self, direction: _Knobs, seconds: float) -> None:
        """Swallow everything in ``direction`` for ``seconds`` from now."""
        self._call("stall", direction.name, seconds)

    def unplug(self) -> None:
        self._call("unplug")

    @property
    def device_tap(self) -> DeviceTap:
        return self._call("tap", "device_tap")

    @property
    def host_tap(self) -> DeviceTap:
        return self._call("tap", "host_tap")

    def describe(self) -> str:
        return self._call("describe")

    def close(self) -> None:
        """Stop the proxy process (asked, then terminated, then killed); idempotent."""
        if self._closed:
            return
        self._closed = True
        try:
            with self._lock:
                self._conn.send(("close",))
                self._conn.poll(5) and self._conn.recv()
        except (OSError, EOFError, BrokenPipeError):
            pass
        self._proc.join(timeout=5)
        if self._proc.is_alive():
            self._proc.terminate()
            self._proc.join(timeout=5)
        if self._proc.is_alive():
            self._proc.kill()
            self._proc.join()
        self._conn.close()

    def __enter__(self) -> LinkProxy:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
