"""A serial link with faults: a pty man-in-the-middle between the host and a device's pty.

Why: the simulated devices can drop, corrupt, delay or truncate whole frames they send, but a real
cable also loses single bytes, flips single bits in both directions and gets unplugged while the
device keeps running. ``LinkProxy`` opens the device's pty like a host would, offers the host a new
pty of its own, and moves bytes between the two on a thread, injecting those faults on the way.

It also *taps* the device's output before any fault is injected (``DeviceTap``): every SAMPLE the
device sent, in device time, whether the host got it or not. That is how the tests see the
device's PWM while the link is down, and how they check the safety invariant: the PWM is never on
more than ``watchdog_ms`` of device time after the last COMMAND the device applied.
"""

from __future__ import annotations

import errno
import os
import random
import select
import threading
import time
import tty
from collections import Counter
from dataclasses import dataclass, field

from rehab_hil.protocol import Command, FaultReport, FrameDecoder, Hello, Sample

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
        self._echo: int | None = None
        self._t_echo = 0
        self._was_on = False
        self.last: Sample | None = None

    def feed(self, data: bytes) -> None:
        for frame in self.decoder.feed(data):
            msg = frame.msg
            if isinstance(msg, Sample):
                self._sample(msg)
            elif isinstance(msg, Hello):
                self.hellos += 1
                self._echo, self._was_on = None, False  # a reboot restarts device time
            elif isinstance(msg, FaultReport):
                self.fault_reports.append(msg)
            elif isinstance(msg, Command):
                self.commands += 1

    def _sample(self, s: Sample) -> None:
        self.n_samples += 1
        self.last = s
        if self.keep:
            self.samples.append(s)
        if self._echo is None or s.cmd_seq_echo != self._echo:
            # a new COMMAND was applied at or before this sample: the watchdog was fed no later than now
            self._echo, self._t_echo = s.cmd_seq_echo, s.device_time_us
        on = bool(s.duty0 or s.duty1)
        since = (s.device_time_us - self._t_echo) & 0xFFFFFFFF
        if on:
            self.worst_on_since_command_us = max(self.worst_on_since_command_us, since)
            if s.faults:
                self.violations += 1
        elif self._was_on and since > 0:
            self.pwm_off_after_command_us.append(since)
        self._was_on = on


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


class LinkProxy:
    """Forward bytes between a device pty and a new host-facing pty, with faults; a context manager.

    ``port`` is the path the host opens. ``down`` (device -> host) and ``up`` (host -> device) hold
    the knobs; ``device_tap`` sees the device's output before faults, ``host_tap`` the host's
    output after them (what the device really received). ``unplug()`` closes the host's side (the
    host reads EIO, like a pulled USB cable) and stops forwarding; the device keeps running and
    stays tapped."""

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
        self._stop = threading.Event()
        self._lock = threading.Lock()
        self.error: BaseException | None = None
        self._thread = threading.Thread(target=self._run, name="link-proxy", daemon=True)
        self._thread.start()

    # ---- knobs --------------------------------------------------------------------------------

    def stall(self, direction: Direction, seconds: float) -> None:
        direction.stall_until = time.perf_counter() + seconds

    def unplug(self) -> None:
        with self._lock:
            if not self.unplugged:
                self.unplugged = True
                os.close(self.master)

    # ---- thread -------------------------------------------------------------------------------

    def _run(self) -> None:
        try:
            while not self._stop.is_set():
                fds = [self.dev] + ([] if self.unplugged else [self.master])
                try:
                    readable, _, _ = select.select(fds, [], [], 0.001)
                except (OSError, ValueError):  # the master was closed under us by unplug()
                    continue
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
                self._release()
                self._flush(True)
                self._flush(False)
        except BaseException as e:  # reported by close(): the tests must not hide a broken proxy
            self.error = e

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
        if not (d.garbage or d.truncate or d._cutting or d.drop_p or d.flip_p):  # fast path: no byte faults
            out = bytearray(data)
        else:
            out = self._damage(data, d)
        if d.delay_s > 0:
            self._held.append((now + d.delay_s, downward, bytes(out)))
        else:
            self._deliver(bytes(out), downward)

    def _damage(self, data: bytes, d: Direction) -> bytearray:
        out = bytearray()
        if d.garbage:
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
        with self._lock:
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
                f"unplugged {self.unplugged}, error {self.error!r}")

    # ---- lifetime -----------------------------------------------------------------------------

    def close(self) -> None:
        """Stop the thread and close every descriptor; re-raises an error the thread hit."""
        self._stop.set()
        self._thread.join(timeout=5)
        self.unplug()
        try:
            os.close(self.dev)
        except OSError:
            pass
        if self.error is not None:
            raise RuntimeError(f"link proxy failed: {self.error!r}") from self.error

    def __enter__(self) -> LinkProxy:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
