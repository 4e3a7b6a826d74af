"""The shared-memory ring: every record crosses whole and in order, a lapped reader counts what it lost and
never takes an overwritten slot for a new record, and the writer counts what it wrote over unread slots."""

from __future__ import annotations

import math
import subprocess
import sys

from hypothesis import given, settings
from hypothesis import strategies as st

from rehab_hil.loop.controllers import Command
from rehab_hil.loop.estimation import State
from rehab_hil.loop.records import CommandRecord, EventRecord, SampleRecord
from rehab_hil.loop.ring import EVENT_TEXT_BYTES, RecordRing, RingReader, RingWriter
from rehab_hil.protocol import Sample

CMD = Command((0.25, 0.0), 1, True, 30.5)


def sample(i: int, analog: dict[str, float] | None = None) -> SampleRecord:
    smp = Sample(1000 * i, i, 7 * i - 3, 512, 100 + i % 7, 2500, 0, 1, 0x3, 0, i & 0xFFFF, 0)
    return SampleRecord(0.5 + i * 1e-3, i * 1e-3, smp, State(i * 1e-3, 0.1 * i, -0.2, analog or {"f": 1.5, "t": 2.5}),
                        CMD, i, 40.0 + i)


def command(i: int) -> CommandRecord:
    return CommandRecord(0.6 + i * 1e-3, i * 1e-3, CMD, i, 41.0, i % 100, 0.25, 3.5, 0.125)


def test_sample_command_and_event_records_cross_whole() -> None:
    ring = RecordRing.create(64)
    try:
        w, r = RingWriter(ring), RingReader(ring, ("f", "t"))
        w.sample(sample(3))
        w.command(command(3))
        w.event(EventRecord(0.003, "temperature", "estimated 133.1 C > 132.8 C"))
        w.sample(SampleRecord(0.0, 0.0, sample(1).sample, None, Command(), -1, math.nan))  # no estimate: none comes
        got = r.take()
        assert got[:3] == [sample(3), command(3), EventRecord(0.003, "temperature", "estimated 133.1 C > 132.8 C")]
        assert got[3].state is None and math.isnan(got[3].temperature_c) and not got[3].command.enable
        assert r.lost == 0 and ring.overflow == 0 and ring.written == 4
    finally:
        ring.close()


def test_an_event_text_longer_than_a_slot_is_cut_and_says_so() -> None:
    ring = RecordRing.create(16)
    try:
        w, r = RingWriter(ring), RingReader(ring)
        w.event(EventRecord(1.0, "link_loss", "x" * 1000))
        (ev,) = r.take()
        assert len(ev.detail.encode()) == EVENT_TEXT_BYTES and ev.detail.endswith("...")
    finally:
        ring.close()


def test_a_lapped_reader_counts_what_it_lost_and_reads_the_rest_in_order() -> None:
    ring = RecordRing.create(32)
    try:
        w, r = RingWriter(ring), RingReader(ring, ("f", "t"))
        for i in range(100):
            w.sample(sample(i))
        got = r.take(limit=1000)
        assert [x.sample.sample_index for x in got] == list(range(68, 100))  # the last 32: the ring's length
        assert r.lost == 68 and ring.overflow == 68  # both ends agree on what was lost
        w.sample(sample(100))
        assert [x.sample.sample_index for x in r.take()] == [100] and r.lost == 68
    finally:
        ring.close()


def test_a_slot_overwritten_while_it_is_read_is_counted_not_taken() -> None:
    ring = RecordRing.create(16)
    try:
        w, r = RingWriter(ring), RingReader(ring)
        w.sample(sample(0))
        w.sample(sample(1))
        at = 128  # the first slot, just after the header: its sequence number now says a later record
        ring.buf[at:at + 8] = (17).to_bytes(8, "little")
        got = r.take()
        assert [x.sample.sample_index for x in got] == [1] and r.lost == 1
    finally:
        ring.close()


@settings(max_examples=60, deadline=None)
@given(st.lists(st.tuples(st.integers(0, 40), st.integers(1, 50)), min_size=1, max_size=20))
def test_whatever_the_pace_every_record_is_read_once_or_counted_lost(steps) -> None:
    ring = RecordRing.create(16)
    try:
        w, r = RingWriter(ring), RingReader(ring)
        written, read = 0, []
        for n_write, limit in steps:
            for _ in range(n_write):
                w.command(command(written))
                written += 1
            read += [x.command_seq for x in r.take(limit)]
        read += [x.command_seq for x in r.take(10_000)]
        assert read == sorted(set(read))  # in order, none twice
        assert len(read) + r.lost == written and read[-1:] == [written - 1][:len(read[-1:])]
        assert ring.overflow <= r.lost  # the writer counts slots it took unread; the reader may also lose a torn one
    finally:
        ring.close()


WRITER = """
import sys
from rehab_hil.loop.ring import RecordRing, RingWriter
from rehab_hil.loop.records import CommandRecord
from rehab_hil.loop.controllers import Command
w = RingWriter(RecordRing.attach(sys.argv[1]))
for i in range(int(sys.argv[2])):
    w.command(CommandRecord(0.0, i * 1e-3, Command(), i, 20.0, i, 0.0, 0.0, 0.0))
"""


def test_records_written_in_another_process_arrive_in_order_and_the_block_outlives_it() -> None:
    ring = RecordRing.create(50_000)
    try:
        subprocess.run([sys.executable, "-c", WRITER, ring.name, "20000"], check=True, timeout=120)
        got = RingReader(ring).take(limit=100_000)
        assert [x.command_seq for x in got] == list(range(20_000))
    finally:
        ring.close()
