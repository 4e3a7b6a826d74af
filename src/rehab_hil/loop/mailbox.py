"""What flows back to a loop process: a few messages in shared memory, taken at the start of a cycle.

The session's process ``post`` s a message (a stop request, a learned table, new thermal values) into
one of ``SLOTS`` slots of a shared block and counts it in the block's header; the loop process looks
at that count once a cycle (one 16-byte read) and, when it moved, copies the waiting message out and
acts on it (``take``). Nothing is sent through a pipe the loop could block on, and the loop never waits
for the poster: a poster finding every slot full waits itself, in its own thread (``post`` 's
``timeout_s``), and is refused after it. A stop request always has a slot (``STOP`` is kept for it).
"""

from __future__ import annotations

import pickle
import struct
import threading
import time
from typing import Any

from rehab_hil.loop.shm import SharedBlock

__all__ = ["Mailbox", "MailboxFull"]

SLOTS = 4  # messages in flight: a table, its re-plan, a thermal update and a stop request at most
SLOT_BYTES = 4 << 20  # one message: the TCP finger's longest table (60 s x 1 kHz x 8 B = 0.5 MB) eight times
_COUNTS = struct.Struct("<QQ")  # posted, taken
_LEN = struct.Struct("<Q")
HEADER_BYTES = 64


class MailboxFull(RuntimeError):
    """The loop process has not taken the messages already posted."""


class Mailbox:
    """The shared block; created by the session's process, attached by name in the loop process
    (mapped directly, as ``loop.ring`` does, so no resource tracker unlinks it)."""

    def __init__(self, block: SharedBlock) -> None:
        self.block, self.name, self.buf = block, block.name, block.buf
        self._lock = threading.Lock()

    @classmethod
    def create(cls) -> Mailbox:
        block = SharedBlock.create(HEADER_BYTES + SLOTS * SLOT_BYTES)
        _COUNTS.pack_into(block.buf, 0, 0, 0)
        return cls(block)

    @classmethod
    def attach(cls, name: str) -> Mailbox:
        return cls(SharedBlock.attach(name))

    def counts(self) -> tuple[int, int]:
        """(posted, taken)."""
        return _COUNTS.unpack_from(self.buf, 0)

    def post(self, message: Any, timeout_s: float = 1.0, stop: bool = False) -> None:
        """Put ``message`` in the next slot (any thread of the session's process); waits up to
        ``timeout_s`` for a free slot, then raises ``MailboxFull``. ``stop``: a stop request, which may
        take the last slot."""
        data = pickle.dumps(message, protocol=pickle.HIGHEST_PROTOCOL)
        if len(data) > SLOT_BYTES - _LEN.size:
            raise ValueError(f"a message of {len(data)} bytes does not fit a mailbox slot ({SLOT_BYTES} B)")
        room = SLOTS if stop else SLOTS - 1
        with self._lock:
            deadline = time.monotonic() + timeout_s
            while True:
                posted, taken = self.counts()
                if posted - taken < room:
                    break
                if time.monotonic() >= deadline:
                    raise MailboxFull(f"{posted - taken} messages not taken by the loop process")
                time.sleep(0.001)
            at = HEADER_BYTES + (posted % SLOTS) * SLOT_BYTES
            _LEN.pack_into(self.buf, at, len(data))
            self.buf[at + _LEN.size:at + _LEN.size + len(data)] = data
            struct.pack_into("<Q", self.buf, 0, posted + 1)  # the count last: the message is whole

    def take(self) -> list[Any]:
        """The loop process's side: every message posted since the last call, oldest first."""
        posted, taken = _COUNTS.unpack_from(self.buf, 0)
        out = []
        while taken < posted:
            at = HEADER_BYTES + (taken % SLOTS) * SLOT_BYTES
            (n,) = _LEN.unpack_from(self.buf, at)
            out.append(pickle.loads(self.buf[at + _LEN.size:at + _LEN.size + n]))
            taken += 1
            struct.pack_into("<Q", self.buf, 8, taken)
        return out

    def waiting(self) -> bool:
        """Messages posted and not taken (the loop's per-cycle look: one read of the header)."""
        posted, taken = _COUNTS.unpack_from(self.buf, 0)
        return posted != taken

    def close(self) -> None:
        """Unmap (and, from the creator, unlink) the block; idempotent."""
        self.buf = None
        self.block.close()
