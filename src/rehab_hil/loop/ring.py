"""The loop process's records in shared memory: one writer, any number of readers, never blocking the writer.

A ``RecordRing`` is a block of ``multiprocessing.shared_memory`` holding a header and ``capacity``
fixed-size slots. The loop process writes every sample, command and event into the next slot
(``RingWriter``): the slot's payload first, its sequence number last, then the header's count of
records written. A reader (``RingReader``, in the session's process) takes the records from its own
position on: a slot whose sequence number is not the one it expects was overwritten before it was
read, and the records lost so are counted (``lost``), never mistaken for new ones. The writer counts
the records it wrote over a slot the reader had not reached (``overflow``): it never waits for a
reader. x86-64 and ARM64 both keep a store's order for a reader that loads the sequence number
before and after the payload (a seqlock); a torn slot is re-read.

The ring is sized in seconds of records at the session's rate (``RING_S``): the longest time the
session's readers (the recorder, zenoh, the twin) may stall without losing anything.
"""

from __future__ import annotations

import math
import operator
import struct
from collections.abc import Sequence
from typing import Any

from rehab_hil.loop.controllers import Command
from rehab_hil.loop.estimation import State
from rehab_hil.loop.records import CommandRecord, EventRecord, SampleRecord
from rehab_hil.loop.shm import SharedBlock
from rehab_hil.protocol import Sample, _sample_of

__all__ = ["RING_S", "SLOT_BYTES", "RecordRing", "RingReader", "RingWriter", "records_per_s"]

# A reader may stall this long without losing a record: a recorder's worst flush on a slow disk and
# the session's process starved beside busy loops both stay far below it (bench/busy_sessions.py)
RING_S = 30.0
SLOT_BYTES = 256  # one record: a sample with its state and command is 171 bytes, an event's text up to 200
MAGIC = 0x52484C31  # "RHL1"
# header: magic, slot size, capacity, records written, reader's next record, records overwritten unread,
# messages posted to the loop process (the inbox's count), the writer's heartbeat (monotonic s)
_HEADER = struct.Struct("<IIQQQQQd")
HEADER_BYTES = 128
# the link's counters, as the loop process last wrote them (the 1 Hz stats of the live views read them)
LINK_FIELDS = ("frames_rx", "frames_tx", "bad_frames", "device_rx_bad_frames", "samples", "dropped_samples",
               "reboots", "request_resends")
_LINK = struct.Struct("<8Q")
_LINK_AT = 64
_W, _R, _OVER, _MAIL, _BEAT = 16, 24, 32, 40, 48  # offsets of the header's counters
_Q = struct.Struct("<Q")
_D = struct.Struct("<d")
_SLOT_HEAD = struct.Struct("<QB")  # sequence number (written last), kind
KIND_SAMPLE, KIND_COMMAND, KIND_EVENT = 1, 2, 3
# sample: host time, time; the 12 wire fields; state t, angle, velocity, 2 analog; command d0, d1,
# direction, enable, reference; command seq, temperature
_SAMPLE = struct.Struct("<dd IIiHHHHBHHHH ddd dd ddBBd id")
_COMMAND = struct.Struct("<dd ddBBd id iddd")
_EVENT = struct.Struct("<d32sH")
EVENT_TEXT_BYTES = SLOT_BYTES - _SLOT_HEAD.size - _EVENT.size
_PAYLOAD = _SLOT_HEAD.size
assert _PAYLOAD + _SAMPLE.size <= SLOT_BYTES and _PAYLOAD + _COMMAND.size <= SLOT_BYTES
_sample_fields = operator.attrgetter("device_time_us", "sample_index", "encoder_count", "adc0", "adc1", "duty0",
                                     "duty1", "direction", "status", "faults", "cmd_seq_echo", "rx_bad_frames")


def records_per_s(rate_hz: float) -> float:
    """Records the loop writes per second at its sample rate: a sample and a command per cycle, with
    room for a burst's extra samples."""
    return 2.5 * rate_hz


class RecordRing:
    """The shared block; ``create`` in the session's process, ``attach`` by name in the loop process."""

    def __init__(self, block: SharedBlock) -> None:
        self.block, self.name, self.owner = block, block.name, block.owner
        self.buf = block.buf
        magic, slot, cap = struct.unpack_from("<IIQ", self.buf, 0)
        if magic != MAGIC or slot != SLOT_BYTES:
            raise ValueError(f"shared memory {self.name} is not a record ring")
        self.capacity = int(cap)

    @classmethod
    def create(cls, capacity: int) -> RecordRing:
        """A new ring of ``capacity`` slots, every page touched now (no page fault in the loop)."""
        if capacity < 16:
            raise ValueError(f"a ring needs at least 16 slots, got {capacity}")
        block = SharedBlock.create(HEADER_BYTES + capacity * SLOT_BYTES)
        block.buf[:] = bytes(len(block.buf))
        _HEADER.pack_into(block.buf, 0, MAGIC, SLOT_BYTES, capacity, 0, 0, 0, 0, 0.0)
        return cls(block)

    @classmethod
    def for_session(cls, rate_hz: float, ring_s: float = RING_S) -> RecordRing:
        return cls.create(max(16, math.ceil(records_per_s(rate_hz) * ring_s)))

    @classmethod
    def attach(cls, name: str) -> RecordRing:
        """The ring ``name`` mapped in this process (the loop process)."""
        return cls(SharedBlock.attach(name))

    @property
    def seconds(self) -> float:
        """How long a reader may stall at 1 kHz (the default rate) without losing a record."""
        return self.capacity / records_per_s(1000.0)

    def counter(self, offset: int) -> int:
        return _Q.unpack_from(self.buf, offset)[0]

    @property
    def written(self) -> int:
        return self.counter(_W)

    @property
    def overflow(self) -> int:
        """Records the writer put over a slot its reader had not reached."""
        return self.counter(_OVER)

    @property
    def mail(self) -> int:
        return self.counter(_MAIL)

    def post_mail(self) -> None:
        """Count one message sent to the loop process (it looks at this count each cycle, not at the pipe)."""
        _Q.pack_into(self.buf, _MAIL, self.mail + 1)

    def link_counts(self) -> dict[str, int]:
        """The link's counters as the loop process last wrote them."""
        return dict(zip(LINK_FIELDS, _LINK.unpack_from(self.buf, _LINK_AT), strict=True))

    @property
    def heartbeat(self) -> float:
        return _D.unpack_from(self.buf, _BEAT)[0]

    def close(self) -> None:
        """Unmap (and, from the creator, unlink) the block; idempotent."""
        self.buf = None
        self.block.close()


class RingWriter:
    """The loop process's end: ``sample``, ``command`` and ``event`` each put one record in the next
    slot. Never blocks; a slot the reader has not reached is overwritten and counted."""

    def __init__(self, ring: RecordRing) -> None:
        self.ring = ring
        self.buf = ring.buf
        self.capacity = ring.capacity
        self.seq = ring.written  # the next record's number
        self.overflow = ring.overflow
        self._room_until = self.seq  # the reader was at least this far: no need to look before it

    def _slot(self) -> int:
        seq = self.seq
        if seq >= self._room_until:  # look at the reader's position only when the last look runs out
            self._room_until = _Q.unpack_from(self.buf, _R)[0] + self.capacity
            if seq >= self._room_until:
                self.overflow += 1
                _Q.pack_into(self.buf, _OVER, self.overflow)
        return HEADER_BYTES + (seq % self.capacity) * SLOT_BYTES

    def _done(self, at: int, kind: int) -> None:
        seq = self.seq
        _SLOT_HEAD.pack_into(self.buf, at, seq + 1, kind)  # the slot's number last: seq + 1 (0 is never written)
        self.seq = seq + 1
        _Q.pack_into(self.buf, _W, seq + 1)

    def sample(self, rec: SampleRecord) -> None:
        at = self._slot()
        st, cmd = rec.state, rec.command
        a = tuple(st.analog.values()) if st is not None else ()
        _SAMPLE.pack_into(self.buf, at + _PAYLOAD, rec.host_time_s, rec.time_s, *_sample_fields(rec.sample),
                          st.t_s if st is not None else math.nan, st.angle_rad if st is not None else math.nan,
                          st.velocity_rad_s if st is not None else math.nan, a[0] if a else math.nan,
                          a[1] if len(a) > 1 else math.nan, cmd.duty[0], cmd.duty[1], cmd.direction, cmd.enable,
                          cmd.reference_deg, rec.command_seq, rec.temperature_c)
        self._done(at, KIND_SAMPLE)

    def command(self, rec: CommandRecord) -> None:
        at = self._slot()
        cmd = rec.command
        _COMMAND.pack_into(self.buf, at + _PAYLOAD, rec.host_time_s, rec.time_s, cmd.duty[0], cmd.duty[1],
                           cmd.direction, cmd.enable, cmd.reference_deg, rec.command_seq, rec.temperature_c, rec.row,
                           rec.error_deg, rec.effort, rec.saturation)
        self._done(at, KIND_COMMAND)

    def event(self, rec: EventRecord) -> None:
        at = self._slot()
        text = rec.detail.encode()
        if len(text) > EVENT_TEXT_BYTES:  # the full text is in the run's result; the record says it was cut
            text = text[:EVENT_TEXT_BYTES - 3] + b"..."
        _EVENT.pack_into(self.buf, at + _PAYLOAD, rec.time_s, rec.kind.encode()[:32], len(text))
        o = at + _PAYLOAD + _EVENT.size
        self.buf[o:o + len(text)] = text
        self._done(at, KIND_EVENT)

    def link(self, stats: Any) -> None:
        """The link's counters (``LinkStats``) for the live views."""
        _LINK.pack_into(self.buf, _LINK_AT, stats.frames_rx, stats.frames_tx, sum(stats.bad_frames.values()),
                        stats.device_rx_bad_frames, stats.samples, stats.dropped_samples, stats.reboots,
                        stats.request_resends)

    def beat(self, now: float) -> None:
        """The writer is alive at ``now`` (monotonic s): a reader tells a quiet loop from a dead one."""
        _D.pack_into(self.buf, _BEAT, now)


class RingReader:
    """The session's end: ``take`` returns the records written since the last call, as the loop's record
    types, and counts the ones overwritten before they were read (``lost``)."""

    def __init__(self, ring: RecordRing, analog_names: Sequence[str] = ()) -> None:
        self.ring = ring
        self.analog = tuple(analog_names)
        self.next = ring.counter(_R)
        self.lost = 0

    def take(self, limit: int = 4096) -> list[Any]:
        """Up to ``limit`` records, oldest first; the reader's position is published for the writer."""
        ring, out = self.ring, []
        buf, cap = ring.buf, ring.capacity
        end = min(ring.written, self.next + limit)
        if end - self.next > cap:  # the writer lapped us: what it overwrote is gone
            self.lost += end - cap - self.next
            self.next = end - cap
        while self.next < end:
            at = HEADER_BYTES + (self.next % cap) * SLOT_BYTES
            rec = self._read(buf, at, self.next + 1)
            if rec is None:  # overwritten while we looked: count it and go on from what is there now
                self.lost += 1
            else:
                out.append(rec)
            self.next += 1
        _Q.pack_into(buf, _R, self.next)
        return out

    def _read(self, buf: Any, at: int, seq: int) -> Any:
        head, kind = _SLOT_HEAD.unpack_from(buf, at)
        if head != seq:
            return None
        if kind == KIND_SAMPLE:
            rec: Any = self._sample(_SAMPLE.unpack_from(buf, at + _PAYLOAD))
        elif kind == KIND_COMMAND:
            rec = _command(_COMMAND.unpack_from(buf, at + _PAYLOAD))
        else:
            t, name, n = _EVENT.unpack_from(buf, at + _PAYLOAD)
            o = at + _PAYLOAD + _EVENT.size
            rec = EventRecord(t, name.rstrip(b"\0").decode(), bytes(buf[o:o + n]).decode(errors="replace"))
        return rec if _SLOT_HEAD.unpack_from(buf, at)[0] == seq else None  # not torn by the writer meanwhile

    def _sample(self, v: tuple[Any, ...]) -> SampleRecord:
        smp: Sample = _sample_of(v[2:14])
        t, angle, vel, a0, a1 = v[14:19]
        analog = dict(zip(self.analog, (a0, a1), strict=False))
        state = None if math.isnan(t) else State(t, angle, vel, analog)
        cmd = Command((v[19], v[20]), v[21], bool(v[22]), v[23])
        return SampleRecord(v[0], v[1], smp, state, cmd, v[24], v[25])


def _command(v: tuple[Any, ...]) -> CommandRecord:
    cmd = Command((v[2], v[3]), v[4], bool(v[5]), v[6])
    return CommandRecord(v[0], v[1], cmd, v[7], v[8], v[9], v[10], v[11], v[12])
