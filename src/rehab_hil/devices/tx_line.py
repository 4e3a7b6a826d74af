"""``TxLine``: a simulated device's outgoing frames and the link faults injected on them.

What the device sends goes out here, framed with its seq, and meets the knobs of the control channel
on the way (``SimDevice._control``): dropped with probability ``drop``, one byte flipped with
probability ``corrupt``, cut in half once (``truncate_next``), held ``delay_s`` (in order: a wire
never reorders), lost during a stall of device time (``stall_until_tick``), or random bytes written
now (``garbage``). A pty that nobody reads loses what does not fit (counted in ``tx_overrun``). Kept
apart from ``SimDevice``, which runs the firmware core, the clock and the plant.
"""

from __future__ import annotations

import errno
import heapq
import math
import os
import random
import time
from collections.abc import Sequence

from rehab_hil.protocol import Message, encode_frame

__all__ = ["TxLine"]


class TxLine:
    """The device end of a pty (``fd``, the master) with the fault knobs and the transmit counters."""

    def __init__(self, fd: int, rng: random.Random) -> None:
        self.fd, self.rng = fd, rng
        self.drop = self.corrupt = 0.0
        self.delay_s = 0.0
        self.truncate_next = False
        self.stall_until_tick = -1  # the last base tick of a stall: device time, whatever the clock or the load
        self.tx_frames = self.tx_dropped = self.tx_overrun = 0
        self._tx_seq = 0
        self._delayed: list[tuple[float, int, bytes]] = []
        self._delayed_n = 0
        self._last_due = 0.0  # when the newest held frame goes out

    def restart(self) -> None:
        """The device was reset: its frames count from seq 0 again, and a stall ends."""
        self.stall_until_tick = -1
        self._tx_seq = 0

    def send(self, msgs: Sequence[Message], tick: int) -> None:
        """Frame and send ``msgs`` at base tick ``tick`` of device time, through the faults."""
        for msg in msgs:
            frame = encode_frame(msg, self._tx_seq)
            self._tx_seq = (self._tx_seq + 1) & 0xFFFF
            self.tx_frames += 1
            now = time.perf_counter()
            if tick <= self.stall_until_tick or (self.drop and self.rng.random() < self.drop):
                self.tx_dropped += 1
                continue
            if self.corrupt and self.rng.random() < self.corrupt:
                buf = bytearray(frame)
                i = self.rng.randrange(len(buf) - 1)
                buf[i] ^= self.rng.randrange(1, 256)
                frame = bytes(buf)
            if self.truncate_next:
                self.truncate_next = False
                frame = frame[: max(1, (len(frame) - 1) // 2)] + b"\x00"
            if self.delay_s > 0 or self._delayed:  # a wire never reorders: after a delay is lifted,
                self._delayed_n += 1                # frames wait behind the ones still held
                self._last_due = max(now + self.delay_s, self._last_due if self._delayed else 0.0)
                heapq.heappush(self._delayed, (self._last_due, self._delayed_n, frame))
            else:
                self.write(frame)

    def next_due(self) -> float:
        """When the oldest held frame goes out (perf_counter; inf when none is held)."""
        return self._delayed[0][0] if self._delayed else math.inf

    def flush_delayed(self) -> None:
        """Send the held frames whose delay has passed."""
        now = time.perf_counter()
        while self._delayed and self._delayed[0][0] <= now:
            self.write(heapq.heappop(self._delayed)[2])

    def garbage(self, n: int) -> None:
        """Write ``n`` random bytes now."""
        self.write(self.rng.randbytes(n))

    def write(self, data: bytes) -> None:
        """Non-blocking write; when nobody reads the pty and its buffer is full, the frame is lost."""
        try:
            n = os.write(self.fd, data)
        except BlockingIOError:
            n = 0
        except OSError as e:
            if e.errno in (errno.EIO, errno.EAGAIN):
                n = 0
            else:
                raise
        if n < len(data):
            self.tx_overrun += 1
            if n:  # a partial frame: terminate it so the host resyncs (it counts one bad frame)
                try:
                    os.write(self.fd, b"\x00")
                except OSError:
                    pass

    def status(self) -> str:
        """The transmit counters, as ``status`` reports them."""
        return f"tx_frames={self.tx_frames} tx_dropped={self.tx_dropped} tx_overrun={self.tx_overrun}"
