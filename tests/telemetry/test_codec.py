from __future__ import annotations

import math
import struct

import pytest

from rehab_hil.protocol import Sample
from rehab_hil.telemetry.codec import (
    STATE_HEADER,
    STATE_RECORD,
    PayloadError,
    StateSample,
    decode_json,
    decode_state,
    encode_json,
    encode_state,
    to_state_sample,
)


def sample(i: int, **kw: object) -> StateSample:
    base = dict(host_time_s=i * 1e-3, device_time_us=i * 1000, sample_index=i, encoder_count=-i, adc0=512,
                adc1=1023, duty0=10_000, duty1=0, direction=1, status=3, faults=0, cmd_seq_echo=i & 0xFFFF,
                rx_bad_frames=2, angle_deg=1.5, force_n=-0.25, temperature_c=25.0, setpoint_deg=2.0, safety="ok")
    base.update(kw)
    return StateSample(**base)  # type: ignore[arg-type]


def test_a_batch_round_trips_every_field_and_keeps_order() -> None:
    samples = [sample(i) for i in range(10)]
    batch = decode_state(encode_state(samples, batch_seq=7, dropped_total=3))
    assert batch.batch_seq == 7 and batch.dropped_total == 3
    assert batch.samples == samples


def test_a_batch_of_ten_is_compact() -> None:
    assert len(encode_state([sample(i) for i in range(10)])) == STATE_HEADER.size + 10 * STATE_RECORD.size < 600


def test_a_protocol_sample_encodes_with_nan_for_unknown_derived_values() -> None:
    raw = Sample(1, 2, -3, 4, 5, 6, 7, 8, 9, 10, 11, 12)
    (s,) = decode_state(encode_state([raw])).samples
    assert (s.device_time_us, s.sample_index, s.encoder_count, s.rx_bad_frames) == (1, 2, -3, 12)
    assert math.isnan(s.angle_deg) and s.safety == "unknown"


def test_an_object_carrying_a_sample_and_derived_values_is_accepted() -> None:
    class Cycle:
        sample = Sample(1, 2, -3, 4, 5, 6, 7, 8, 9, 10, 11, 12)
        host_time_s = 0.5
        angle_deg = 12.0
        safety = "tripped"

    s = to_state_sample(Cycle())
    assert (s.host_time_s, s.angle_deg, s.safety, s.sample_index) == (0.5, 12.0, "tripped", 2)


def test_an_object_without_sample_fields_is_refused() -> None:
    with pytest.raises(PayloadError, match="lacks SAMPLE fields"):
        encode_state([object()])


def test_out_of_range_fields_are_refused_not_wrapped() -> None:
    with pytest.raises(PayloadError, match="out of range"):
        encode_state([sample(1, adc0=70_000)])


def test_empty_and_oversized_batches_are_refused() -> None:
    with pytest.raises(PayloadError):
        encode_state([])
    with pytest.raises(PayloadError):
        encode_state([sample(0)] * 1001)


@pytest.mark.parametrize(("mutate", "msg"), [
    (lambda b: b[:5], "too short"),
    (lambda b: b"XX" + b[2:], "magic"),
    (lambda b: b[:2] + bytes([9]) + b[3:], "version 9"),
    (lambda b: b[:3] + bytes([5]) + b[4:], "kind"),
    (lambda b: b[:-1], "header says"),
])
def test_malformed_state_payloads_raise_payload_error(mutate, msg: str) -> None:  # type: ignore[no-untyped-def]
    with pytest.raises(PayloadError, match=msg):
        decode_state(mutate(encode_state([sample(0), sample(1)])))


def test_a_longer_record_from_a_later_revision_is_read_by_its_known_prefix() -> None:
    rec = STATE_RECORD.pack(0.5, *sample(1)[1:13], 1.0, 2.0, 3.0, 4.0, 1) + b"\x00" * 6
    payload = STATE_HEADER.pack(b"RS", 1, 1, 1, STATE_RECORD.size + 6, 0, 0) + rec
    (s,) = decode_state(payload).samples
    assert s.host_time_s == 0.5 and s.setpoint_deg == 4.0 and s.safety == "ok"


def test_json_messages_carry_version_and_kind_and_map_nan_to_null() -> None:
    msg = decode_json(encode_json("stats", {"loop": {"p99_us": float("nan"), "n": 3}}), expect="stats")
    assert msg == {"v": 1, "kind": "stats", "loop": {"p99_us": None, "n": 3}}


@pytest.mark.parametrize(("payload", "msg"), [
    (b"\xff", "not a JSON"), (b"[1]", "object"), (b'{"v":2,"kind":"stats"}', "version 2"),
    (b'{"v":1,"kind":"nope"}', "unknown message kind"), (b'{"v":1,"kind":"info"}', "expected a 'stats'"),
])
def test_malformed_json_messages_raise_payload_error(payload: bytes, msg: str) -> None:
    with pytest.raises(PayloadError, match=msg):
        decode_json(payload, expect="stats")


def test_unknown_json_kinds_and_reserved_keys_are_refused_when_encoding() -> None:
    with pytest.raises(PayloadError):
        encode_json("weather", {})
    with pytest.raises(PayloadError, match="reserved"):
        encode_json("stats", {"v": 2})


def test_record_layout_matches_the_documented_size() -> None:
    assert STATE_RECORD.size == struct.calcsize("<d") + 29 + 16 + 1 == 54
