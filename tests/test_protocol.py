"""Protocol v1 codec: round trips, the CRC check value, and a decoder that never raises and resyncs."""

from __future__ import annotations

import struct

import pytest
from cobs import cobs
from hypothesis import given, settings
from hypothesis import strategies as st

from rehab_hil import protocol as p

U8, U16, U32 = st.integers(0, 0xFF), st.integers(0, 0xFFFF), st.integers(0, 0xFFFFFFFF)
I32 = st.integers(-(2**31), 2**31 - 1)
_FIELD = {"B": U8, "H": U16, "I": U32, "i": I32}


def _strategy(cls: type[p.Message]) -> st.SearchStrategy[p.Message]:
    codes = cls.FMT.format.lstrip("<")
    return st.tuples(*(_FIELD[c] for c in codes)).map(lambda vals: cls(*vals))


messages = st.one_of(*(_strategy(c) for c in p.MESSAGE_TYPES.values()))
seqs = st.integers(0, 0xFFFF)


def test_crc_matches_the_ccitt_false_check_value() -> None:
    assert p.crc16_ccitt_false(b"123456789") == 0x29B1


def _crc_bitwise(data: bytes) -> int:
    """The CRC from its definition (poly 0x1021, init 0xFFFF, MSB first): an independent oracle."""
    crc = 0xFFFF
    for byte in data:
        crc ^= byte << 8
        for _ in range(8):
            crc = ((crc << 1) ^ 0x1021) & 0xFFFF if crc & 0x8000 else (crc << 1) & 0xFFFF
    return crc


@given(st.binary(max_size=64))
def test_crc_equals_the_bitwise_definition(data: bytes) -> None:
    assert p.crc16_ccitt_false(data) == _crc_bitwise(data)


def test_frame_sizes_fit_1khz_at_1mbaud() -> None:
    sample = p.encode_frame(p.Sample(*([0] * 12)), 0)
    command = p.encode_frame(p.CommandFrame(0, 0, 0, 0), 0)
    assert (len(sample), len(command)) == (37, 14)
    assert len(sample) * 10 * 1000 < 1_000_000 / 2  # bits per second at 1 kHz: under half the link


def test_documented_test_vectors_encode_exactly() -> None:
    assert p.encode_frame(p.HelloReq(), 0).hex() == "030101010344c500"
    assert p.encode_frame(p.CommandFrame(5000, 0, 0, 1), 7).hex() == "0401030703881301010401eb4700"


@given(messages, seqs)
def test_every_message_round_trips_through_a_frame(msg: p.Message, seq: int) -> None:
    frame = p.encode_frame(msg, seq)
    assert frame.endswith(b"\x00") and b"\x00" not in frame[:-1]
    assert p.FrameDecoder().feed(frame) == [p.Frame(seq, msg)]


@given(st.lists(st.tuples(messages, seqs), max_size=20), st.integers(1, 40))
def test_frames_split_into_arbitrary_chunks_decode_in_order(items: list, chunk: int) -> None:
    wire = b"".join(p.encode_frame(m, s) for m, s in items)
    dec = p.FrameDecoder()
    out = []
    for i in range(0, len(wire), chunk):
        out += dec.feed(wire[i:i + chunk])
    assert out == [p.Frame(s, m) for m, s in items]
    assert dec.bad_total == 0


@settings(max_examples=300)
@given(st.binary(max_size=400))
def test_any_byte_stream_never_raises(data: bytes) -> None:
    dec = p.FrameDecoder()
    frames = dec.feed(data)
    assert all(isinstance(f, p.Frame) for f in frames)
    assert set(dec.bad) <= set(p.BAD_KINDS)


@given(st.binary(max_size=300), messages, seqs)
def test_decoder_resyncs_after_garbage(garbage: bytes, msg: p.Message, seq: int) -> None:
    dec = p.FrameDecoder()
    dec.feed(garbage)
    # one delimiter ends whatever the garbage left half-open; the next frame decodes
    assert dec.feed(b"\x00" + p.encode_frame(msg, seq)) == [p.Frame(seq, msg)]


@given(messages, seqs, st.data())
def test_a_flipped_byte_is_never_delivered_as_the_original(msg: p.Message, seq: int, data: st.DataObject) -> None:
    frame = bytearray(p.encode_frame(msg, seq))
    i = data.draw(st.integers(0, len(frame) - 2))
    frame[i] ^= data.draw(st.integers(1, 255))
    dec = p.FrameDecoder()
    out = dec.feed(bytes(frame) + b"\x00")
    assert p.Frame(seq, msg) not in out
    assert dec.bad_total >= 1


def _frame(packet: bytes) -> bytes:
    return cobs.encode(packet) + b"\x00"


def _packet(version: int, mtype: int, payload: bytes, seq: int = 3) -> bytes:
    body = struct.pack("<BBH", version, mtype, seq) + payload
    return body + struct.pack("<H", p.crc16_ccitt_false(body))


@pytest.mark.parametrize(("wire", "kind"), [
    (_frame(b"\x01\x02\x03"), "short"),
    (_frame(_packet(1, 0x03, bytes(6))[:-1] + b"\x00"), "crc"),
    (_frame(_packet(2, 0x03, bytes(6))), "version"),
    (_frame(_packet(1, 0x7F, b"")), "type"),
    (_frame(_packet(1, 0x03, bytes(5))), "length"),
    (b"\x05\x01\x00", "cobs"),
    (b"\x01" * 70 + b"\x00", "overflow"),
])
def test_each_kind_of_bad_frame_is_counted_and_dropped(wire: bytes, kind: str) -> None:
    dec = p.FrameDecoder()
    good = p.encode_frame(p.Heartbeat(42), 9)
    assert dec.feed(wire + good) == [p.Frame(9, p.Heartbeat(42))]
    assert dict(dec.bad) == {kind: 1}


def test_empty_frames_are_ignored_and_not_counted() -> None:
    dec = p.FrameDecoder()
    assert dec.feed(b"\x00\x00\x00") == []
    assert dec.bad_total == 0


def test_truncated_frame_is_counted_and_the_next_one_decodes() -> None:
    full = p.encode_frame(p.Sample(*range(12)), 5)
    dec = p.FrameDecoder()
    out = dec.feed(full[:17] + b"\x00" + full)
    assert out == [p.Frame(5, p.Sample(*range(12)))]
    assert dec.bad_total == 1


def test_payload_out_of_wire_range_is_refused_on_encode() -> None:
    with pytest.raises(struct.error):
        p.encode_frame(p.CommandFrame(70_000, 0, 0, 1), 0)


@pytest.mark.parametrize(("rate", "k"), [(1000, 1), (500, 2), (333, 3), (300, 3), (250, 4), (1, 1000),
                                         (5000, 1), (667, 1), (666, 2)])
def test_sample_rate_divider_picks_the_nearest_supported_rate(rate: int, k: int) -> None:
    assert p.nearest_rate_divider(rate) == k
