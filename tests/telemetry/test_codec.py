from __future__ import annotations

import enum
import math

import pytest

from rehab_hil.loop.controllers import Command
from rehab_hil.loop.estimation import State
from rehab_hil.loop.records import CommandRecord, SampleRecord
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
    pack_record,
    to_state_sample,
)


def sample(i: int, **kw: object) -> StateSample:
    base = dict(host_time_s=100 + i * 1e-3, time_s=i * 1e-3, has_sample=True, device_time_us=i * 1000,
                sample_index=i, encoder_count=-i, adc0=512, adc1=1023, duty0=10_000, duty1=0, direction=1, status=3,
                faults=0, cmd_seq_echo=i & 0xFFFF, rx_bad_frames=2, has_state=True, state_t_s=i * 1e-3,
                angle_rad=0.1 * i, velocity_rad_s=-1.0 / 3.0, analog=(0.123456789012345,), command_duty0=0.25,
                command_duty1=0.0, command_direction=1, command_enable=True, reference_deg=12.5, command_seq=i,
                temperature_c=25.0 + i / 7, safety="ok")
    base.update(kw)
    return StateSample(**base)  # type: ignore[arg-type]


def test_a_batch_round_trips_every_field_and_keeps_order() -> None:
    samples = [sample(i) for i in range(10)]
    batch = decode_state(encode_state(samples, batch_seq=7, dropped_total=3))
    assert batch.batch_seq == 7 and batch.dropped_total == 3
    assert batch.samples == samples


def test_a_batch_of_ten_is_one_header_plus_ten_records() -> None:
    assert len(encode_state([sample(i) for i in range(10)])) == STATE_HEADER.size + 10 * STATE_RECORD.size == 1256


def test_a_protocol_sample_encodes_with_nan_for_unknown_derived_values() -> None:
    raw = Sample(1, 2, -3, 4, 5, 6, 7, 8, 9, 10, 11, 12)
    (s,) = decode_state(encode_state([raw])).samples
    assert (s.device_time_us, s.sample_index, s.encoder_count, s.rx_bad_frames) == (1, 2, -3, 12)
    assert s.has_sample and not s.has_state and math.isnan(s.angle_rad) and s.safety == "unknown"


def test_a_recorder_record_round_trips_exactly() -> None:
    rec = SampleRecord(host_time_s=12.345678901234, time_s=0.001, sample=Sample(1, 2, -3, 4, 5, 6, 7, 1, 9, 10, 11, 12),
                       state=State(0.001, 0.1234567890123, -2.5, {"torque_nm": 0.3333333333333}),
                       command=Command((0.5, 0.125), 1, True, 33.3), command_seq=77, temperature_c=31.25)
    (s,) = decode_state(encode_state([rec])).samples
    assert (s.host_time_s, s.time_s, s.angle_rad, s.velocity_rad_s) == (12.345678901234, 0.001, 0.1234567890123, -2.5)
    assert s.analog == (0.3333333333333,) and s.has_state and s.has_sample
    assert (s.command_duty0, s.command_duty1, s.command_direction, s.command_enable) == (0.5, 0.125, 1, True)
    assert (s.reference_deg, s.command_seq, s.temperature_c) == (33.3, 77, 31.25)


def test_a_cycle_without_a_sample_keeps_its_command() -> None:
    rec = CommandRecord(1.0, 0.0, Command(), 5, float("nan"))
    (s,) = decode_state(encode_state([rec])).samples
    assert not s.has_sample and not s.has_state and s.command_seq == 5 and not s.command_enable


def test_a_safety_enum_is_carried_by_value() -> None:
    class Safety(enum.Enum):
        TRIPPED = "tripped"

    class Cycle:
        sample = Sample(1, 2, -3, 4, 5, 6, 7, 8, 9, 10, 11, 12)
        safety = Safety.TRIPPED

    assert to_state_sample(Cycle()).safety == "tripped"


def test_an_object_without_sample_state_or_command_is_refused() -> None:
    with pytest.raises(PayloadError, match="neither SAMPLE fields"):
        encode_state([object()])


def test_more_analog_signals_than_the_format_holds_are_refused() -> None:
    with pytest.raises(PayloadError, match="at most 2 analog"):
        encode_state([sample(0, analog=(1.0, 2.0, 3.0))])


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
    full = encode_state([sample(3)])
    payload = bytearray(full[:STATE_HEADER.size] + full[STATE_HEADER.size:] + b"\x00" * 6)
    payload[6:8] = (STATE_RECORD.size + 6).to_bytes(2, "little")
    (s,) = decode_state(bytes(payload)).samples
    assert s == sample(3)


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
    assert STATE_RECORD.size == 8 + 8 + 1 + 29 + 5 * 8 + 2 * 8 + 1 + 8 + 4 + 8 + 1 == 124


def test_the_record_fast_path_packs_the_same_bytes_as_the_general_path() -> None:
    recs = [SampleRecord(3.5, 0.002, Sample(9, 8, -7, 6, 5, 4, 3, 1, 2, 1, 0, 1),
                         State(0.002, 1.25, -0.5, {"a_n": 2.0, "b_n": -1.0}),
                         Command((0.75, 0.5), 2, False, float("nan")), 4, 40.5),
            CommandRecord(3.6, 0.003, Command((0.0, 0.0), 0, True, 1.0), 5, 41.0)]
    assert pack_record(recs[0]) == pack_record(to_state_sample(recs[0]))
    assert encode_state(recs) == encode_state([to_state_sample(r) for r in recs])
    (a, b) = decode_state(encode_state(recs)).samples
    assert a.analog == (2.0, -1.0) and not a.command_enable and math.isnan(a.reference_deg)
    assert not b.has_sample and b.command_enable
