"""Fuzzing the protocol v1 streaming decoder (docs/protocol.md) with hypothesis.

What the host loop relies on: ``FrameDecoder.feed`` never raises and never hangs whatever arrives
on the wire; every delimited frame is either returned or counted as bad (nothing silently vanishes);
the result does not depend on how the stream is cut into reads; after garbage the decoder
resynchronises at the next 0x00; and a packet damaged by a short burst of bit errors is never
accepted as a valid (but wrong) message, which is what CRC-16/CCITT-FALSE guarantees.
"""

from __future__ import annotations

from cobs import cobs
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from rehab_hil.protocol import (
    BAD_KINDS,
    MAX_FRAME,
    Ack,
    Clear,
    CommandFrame,
    Configure,
    DeviceHeartbeat,
    EStop,
    FaultReport,
    Frame,
    FrameDecoder,
    Heartbeat,
    Hello,
    HelloReq,
    Message,
    Sample,
    encode_frame,
    encode_packet,
)

FUZZ = settings(max_examples=200, deadline=None, suppress_health_check=[HealthCheck.too_slow])

u8, u16, u32 = st.integers(0, 0xFF), st.integers(0, 0xFFFF), st.integers(0, 0xFFFF_FFFF)
i32 = st.integers(-(2**31), 2**31 - 1)

messages: st.SearchStrategy[Message] = st.one_of(
    st.just(HelloReq()),
    st.just(EStop()),
    st.just(Clear()),
    st.builds(Configure, u16, u16, u16, u32, u16, i32, i32, u8),
    st.builds(CommandFrame, u16, u16, u8, u8),
    st.builds(Heartbeat, u32),
    st.builds(Hello, u8, u8, u8, u8, u8, u8, u16, u16, u8, u16, u8),
    st.builds(Sample, u32, u32, i32, u16, u16, u16, u16, u8, u16, u16, u16, u16),
    st.builds(FaultReport, u16, u16),
    st.builds(DeviceHeartbeat, u32),
    st.builds(Ack, u8, u16, u8),
)
frames = st.tuples(messages, u16).map(lambda mt: Frame(mt[1], mt[0]))


def expected_outcomes(stream: bytes) -> int:
    """How many frames + bad counts a stream must produce: one per non-empty delimited segment
    (an over-long one counts once as overflow), plus one overflow for an over-long unterminated tail."""
    *done, tail = stream.split(b"\x00")
    return sum(1 for s in done if s) + (1 if len(tail) > MAX_FRAME else 0)


def feed_in_chunks(dec: FrameDecoder, stream: bytes, cuts: list[int]) -> list[Frame]:
    out: list[Frame] = []
    pos = 0
    for cut in sorted(c % (len(stream) + 1) for c in cuts):
        out += dec.feed(stream[pos:cut])
        pos = max(pos, cut)
    out += dec.feed(stream[pos:])
    return out


@FUZZ
@given(stream=st.binary(max_size=2000), cuts=st.lists(st.integers(0, 4000), max_size=20))
def test_arbitrary_bytes_never_raise_and_every_segment_is_a_frame_or_a_counted_drop(stream, cuts):
    dec = FrameDecoder()
    out = feed_in_chunks(dec, stream, cuts)
    assert set(dec.bad) <= set(BAD_KINDS)
    assert dec.frames == len(out)
    assert len(out) + dec.bad_total == expected_outcomes(stream)


@FUZZ
@given(stream=st.binary(max_size=1500), cuts=st.lists(st.integers(0, 3000), max_size=20))
def test_decoding_does_not_depend_on_how_the_stream_is_split_into_reads(stream, cuts):
    whole, split = FrameDecoder(), FrameDecoder()
    assert feed_in_chunks(split, stream, cuts) == whole.feed(stream)
    assert split.bad == whole.bad


@FUZZ
@given(sent=st.lists(frames, min_size=1, max_size=20), cuts=st.lists(st.integers(0, 2000), max_size=10))
def test_valid_frames_round_trip_through_any_read_split(sent, cuts):
    stream = b"".join(encode_frame(f.msg, f.seq) for f in sent)
    dec = FrameDecoder()
    assert feed_in_chunks(dec, stream, cuts) == sent
    assert dec.bad_total == 0


@FUZZ
@given(garbage=st.binary(max_size=400), frame=frames)
def test_decoder_resynchronises_at_the_next_delimiter_after_any_garbage(garbage, frame):
    dec = FrameDecoder()
    out = dec.feed(garbage)
    out += dec.feed(b"\x00" + encode_frame(frame.msg, frame.seq))
    assert out[-1] == frame


@st.composite
def mutated_streams(draw: st.DrawFn) -> tuple[list[Frame], bytes, list[str]]:
    """Valid frames, each either intact ("none") or damaged (bit flip, byte drop, byte insert,
    truncation that loses the delimiter, garbage prepended); returns frames, stream and mutation kinds."""
    sent = draw(st.lists(frames, min_size=1, max_size=12))
    parts: list[bytes] = []
    kinds: list[str] = []
    for f in sent:
        wire = bytearray(encode_frame(f.msg, f.seq))
        body = len(wire) - 1  # keep the delimiter unless the mutation is a truncation
        kind = draw(st.sampled_from(["none", "none", "flip", "drop", "insert", "truncate", "garbage"]))
        if kind == "flip":
            i = draw(st.integers(0, body - 1))
            wire[i] ^= 1 << draw(st.integers(0, 7))
        elif kind == "drop":
            del wire[draw(st.integers(0, body - 1))]
        elif kind == "insert":
            wire.insert(draw(st.integers(0, body)), draw(st.integers(0, 255)))
        elif kind == "truncate":
            wire = wire[: draw(st.integers(0, body - 1))]  # the delimiter is lost too
        elif kind == "garbage":
            wire = bytearray(draw(st.binary(min_size=1, max_size=200))) + wire
        parts.append(bytes(wire))
        kinds.append(kind)
    return sent, b"".join(parts), kinds


@FUZZ
@given(case=mutated_streams(), cuts=st.lists(st.integers(0, 3000), max_size=10))
def test_mutated_streams_never_raise_and_keep_every_frame_whose_neighbours_are_intact(case, cuts):
    sent, stream, kinds = case
    dec = FrameDecoder()
    out = feed_in_chunks(dec, stream, cuts)
    assert len(out) + dec.bad_total == expected_outcomes(stream)
    # only a truncation loses a delimiter, and then the damaged frame swallows the one after it;
    # every other intact frame must come through, damage around it notwithstanding
    for k, f in enumerate(sent):
        if kinds[k] == "none" and (k == 0 or kinds[k - 1] != "truncate"):
            assert f in out


@FUZZ
@given(frame=frames, data=st.data())
def test_a_packet_with_a_burst_of_up_to_16_bit_errors_is_always_rejected(frame, data):
    # damage the packet itself (before COBS) so the frame structure is intact and the CRC alone must catch it
    packet = bytearray(encode_packet(frame.msg, frame.seq))
    nbits = len(packet) * 8
    start = data.draw(st.integers(0, nbits - 1))
    width = data.draw(st.integers(1, min(16, nbits - start)))
    pattern = data.draw(st.integers(1, (1 << width) - 1).filter(lambda p: p & 1 and p >> (width - 1)))
    for j in range(width):
        if pattern >> j & 1:
            bit = start + j
            packet[bit // 8] ^= 0x80 >> (bit % 8)
    dec = FrameDecoder()
    out = dec.feed(cobs.encode(bytes(packet)) + b"\x00")
    assert out == []
    assert dec.bad_total == 1


ONE_OF_EACH = [
    Frame(1, HelloReq()), Frame(2, EStop()), Frame(3, Clear()),
    Frame(0x1234, Configure(1000, 50, 10_000, 600_000, 1023, -2000, 2000, 1)),
    Frame(0xFFFF, CommandFrame(7500, 0, 1, 1)), Frame(9, Heartbeat(123_456)),
    Frame(0, Hello(1, 0, 1, 0, 2, 2, 2000, 5000, 10, 1000, 1)),
    Frame(40_000, Sample(1_000_000, 1000, -5, 512, 1023, 10_000, 0, 1, 0x23, 0, 0xFFFE, 3)),
    Frame(77, FaultReport(4, 5)), Frame(78, DeviceHeartbeat(0xFFFF_FFFF)), Frame(79, Ack(2, 0x1234, 0)),
]


def test_every_single_bit_flip_on_the_wire_of_every_message_type_is_dropped_and_counted():
    # exhaustive, not sampled: a flipped bit may hit a COBS code byte (moving zeros around) or
    # create a delimiter; either way no frame may come out and every resulting segment is counted
    for frame in ONE_OF_EACH:
        wire = encode_frame(frame.msg, frame.seq)
        for i in range(len(wire) - 1):
            for b in range(8):
                bad = bytearray(wire)
                bad[i] ^= 1 << b
                dec = FrameDecoder()
                assert dec.feed(bytes(bad)) == [], (frame, i, b)
                assert dec.bad_total == expected_outcomes(bytes(bad))


def test_a_megabyte_of_garbage_without_delimiter_is_dropped_as_one_overflow_with_bounded_buffer():
    dec = FrameDecoder()
    blob = bytes(range(1, 256)) * 4096
    for i in range(0, len(blob), 4096):
        assert dec.feed(blob[i : i + 4096]) == []
    assert dec.bad == {"overflow": 1}
    assert len(dec._buf) <= MAX_FRAME
    f = Frame(7, CommandFrame(5000, 0))
    assert dec.feed(b"\x00" + encode_frame(f.msg, f.seq)) == [f]
