"""Telemetry payloads, versioned: batched binary state records for 1 kHz samples, JSON for the rest.

The schema is docs/telemetry.md ("Payloads"); this module is its only implementation, so
subscribers decode with ``decode_state`` / ``decode_json`` and never re-implement the layout.
"""

from __future__ import annotations

import json
import math
import operator
import struct
from collections.abc import Iterable, Mapping
from typing import Any, NamedTuple

from rehab_hil.loop.records import CommandRecord, SampleRecord

__all__ = [
    "JSON_KINDS",
    "JSON_VERSION",
    "MAX_ANALOG",
    "MAX_BATCH",
    "SAFETY_STATES",
    "STATE_HEADER",
    "STATE_MAGIC",
    "STATE_RECORD",
    "STATE_VERSION",
    "PayloadError",
    "StateBatch",
    "StateSample",
    "decode_json",
    "decode_state",
    "encode_json",
    "encode_state",
    "join_records",
    "pack_record",
    "to_state_sample",
]

STATE_VERSION = 1
JSON_VERSION = 1
STATE_MAGIC = b"RS"
# magic:2s, version:u8, kind:u8 (1 = state batch), count:u16, record_size:u16,
# batch_seq:u32 (publisher's batch counter), dropped_total:u32 (samples the publisher dropped so far)
STATE_HEADER = struct.Struct("<2sBBHHII")
_KIND_STATE = 1
# One loop cycle, exactly what the local recorder sees (docs/telemetry.md, "State record v1"):
# host_time_s:f64, time_s:f64, flags:u8 (bit0 sample present, bit1 state present, bit2 command enable,
# bits3-4 number of analog values),
# the 12 protocol SAMPLE fields (docs/protocol.md), state_t_s, angle_rad, velocity_rad_s, analog0, analog1:
# f64, command_duty0, command_duty1: f64, command_direction:u8, reference_deg:f64, command_seq:u32,
# temperature_c:f64, safety:u8 (index into SAFETY_STATES)
STATE_RECORD = struct.Struct("<ddB" + "IIiHHHHBHHHH" + "ddddd" + "ddBdI" + "dB")
MAX_BATCH = 1000
MAX_ANALOG = 2
SAFETY_STATES = ("unknown", "ok", "warning", "tripped", "estop", "link_lost")
JSON_KINDS = ("stats", "safety", "info", "command", "prediction", "model_mismatch")  # the last two: the live twin

_RAW = ("device_time_us", "sample_index", "encoder_count", "adc0", "adc1", "duty0", "duty1",
        "direction", "status", "faults", "cmd_seq_echo", "rx_bad_frames")
_NAN = math.nan


class PayloadError(ValueError):
    """A payload that is not a telemetry message this version understands."""


class StateSample(NamedTuple):
    """One loop cycle as published: times, the raw device SAMPLE, the host's estimate, the command sent.

    ``has_sample`` is False for a cycle in which no SAMPLE arrived (raw fields are then 0);
    ``has_state`` is False when there is no estimate (state fields NaN). ``analog`` values are the
    calibrated ADC signals in the plant binding's channel order (names come with ``.../info``)."""

    host_time_s: float
    time_s: float
    has_sample: bool
    device_time_us: int
    sample_index: int
    encoder_count: int
    adc0: int
    adc1: int
    duty0: int  # applied duty, duty units (protocol.DUTY_FULL = 1.0)
    duty1: int
    direction: int
    status: int
    faults: int
    cmd_seq_echo: int
    rx_bad_frames: int
    has_state: bool
    state_t_s: float
    angle_rad: float
    velocity_rad_s: float
    analog: tuple[float, ...]
    command_duty0: float  # commanded duty ratio 0..1
    command_duty1: float
    command_direction: int
    command_enable: bool
    reference_deg: float
    command_seq: int
    temperature_c: float
    safety: str

    @property
    def angle_deg(self) -> float:
        return math.degrees(self.angle_rad)


class StateBatch(NamedTuple):
    """A decoded state payload: the publisher's batch counter and drop count, and its samples."""

    batch_seq: int
    dropped_total: int
    samples: list[StateSample]


def _get(obj: Any, name: str, default: Any) -> Any:
    if isinstance(obj, Mapping):
        return obj.get(name, default)
    return getattr(obj, name, default)


def to_state_sample(obj: Any) -> StateSample:
    """Convert what the loop offers into a ``StateSample``.

    Accepts a ``StateSample``; the loop's ``SampleRecord`` (host_time_s, time_s, sample, state, command,
    command_seq, temperature_c) or ``CommandRecord``; a bare ``protocol.Sample``; or any object/mapping
    with those names.
    A ``safety`` attribute (str or Enum) is carried when present."""
    if isinstance(obj, StateSample):
        return obj
    raw = _get(obj, "sample", obj)
    has_sample = raw is not None and all(_get(raw, f, None) is not None for f in _RAW)
    if raw is not obj and raw is not None and not has_sample:
        raise PayloadError(f"{type(raw).__name__} lacks the SAMPLE fields {list(_RAW)}")
    state = _get(obj, "state", None)
    if not has_sample and state is None and _get(obj, "command", None) is None:
        raise PayloadError(f"{type(obj).__name__} has neither SAMPLE fields nor a state or command")
    rawvals = [int(_get(raw, f, 0)) for f in _RAW] if has_sample else [0] * len(_RAW)
    if state is not None:
        analog = tuple(float(v) for v in _get(state, "analog", {}).values())
        if len(analog) > MAX_ANALOG:
            raise PayloadError(f"at most {MAX_ANALOG} analog signals fit the wire format, got {len(analog)}")
        st = (True, float(state.t_s), float(state.angle_rad), float(state.velocity_rad_s), analog)
    else:
        st = (False, _NAN, _NAN, _NAN, ())
    cmd = _get(obj, "command", None)
    if cmd is not None:
        duty = tuple(cmd.duty)
        cm = (float(duty[0]), float(duty[1]), int(cmd.direction), bool(cmd.enable), float(cmd.reference_deg))
    else:
        cm = (_NAN, _NAN, 0, False, _NAN)
    safety = _get(obj, "safety", "unknown")
    safety = str(getattr(safety, "value", safety))
    host_t = float(_get(obj, "host_time_s", _NAN))
    time_s = float(_get(obj, "time_s", _NAN))
    return StateSample(host_t, time_s, has_sample, *rawvals, *st, *cm, int(_get(obj, "command_seq", 0)),
                       float(_get(obj, "temperature_c", _NAN)), safety)


_RAW_GET = operator.attrgetter(*_RAW)
_NO_RAW = (0,) * len(_RAW)
_SAFETY_CODE = {name: i for i, name in enumerate(SAFETY_STATES)}


def _record_values(r: SampleRecord | CommandRecord) -> tuple[Any, ...]:
    """Wire values of a loop record without building a ``StateSample``: the hot path."""
    c = r.command
    if type(r) is SampleRecord:
        flags = 1
        raw = _RAW_GET(r.sample)
        st = r.state
    else:
        flags = 0
        raw = _NO_RAW
        st = None
    if st is not None:
        a = tuple(st.analog.values())
        n = len(a)
        if n > MAX_ANALOG:
            raise PayloadError(f"at most {MAX_ANALOG} analog signals fit the wire format, got {n}")
        flags |= 2 | n << 3
        a0 = a[0] if n > 0 else _NAN
        a1 = a[1] if n > 1 else _NAN
        stv = (st.t_s, st.angle_rad, st.velocity_rad_s, a0, a1)
    else:
        stv = (_NAN, _NAN, _NAN, _NAN, _NAN)
    if c.enable:
        flags |= 4
    safety = getattr(r, "safety", "unknown")
    code = _SAFETY_CODE.get(getattr(safety, "value", safety), 0)
    return (r.host_time_s, r.time_s, flags, *raw, *stv, c.duty[0], c.duty[1], c.direction, c.reference_deg,
            r.command_seq, r.temperature_c, code)


def _sample_values(r: StateSample) -> tuple[Any, ...]:
    if len(r.analog) > MAX_ANALOG:
        raise PayloadError(f"at most {MAX_ANALOG} analog signals fit the wire format, got {len(r.analog)}")
    flags = int(r.has_sample) | int(r.has_state) << 1 | int(r.command_enable) << 2 | len(r.analog) << 3
    a = (*r.analog, _NAN, _NAN)[:MAX_ANALOG]
    return (r.host_time_s, r.time_s, flags, *r[3:15], r.state_t_s, r.angle_rad, r.velocity_rad_s, *a,
            r.command_duty0, r.command_duty1, r.command_direction, r.reference_deg, r.command_seq,
            r.temperature_c, _SAFETY_CODE.get(r.safety, 0))


def _values(obj: Any) -> tuple[Any, ...]:
    if type(obj) is StateSample:
        return _sample_values(obj)
    if type(obj) is SampleRecord or type(obj) is CommandRecord:
        try:
            return _record_values(obj)
        except (AttributeError, TypeError, IndexError):
            pass  # not quite a loop record: take the general path, which explains what is missing
    return _sample_values(to_state_sample(obj))


def pack_record(obj: Any) -> bytes:
    """One record of the state encoding (what ``encode_state`` packs per sample; ``PayloadError`` on bad input)."""
    v = _values(obj)
    try:
        return STATE_RECORD.pack(*v)
    except struct.error as e:
        raise PayloadError(f"sample {v[4]}: field out of range for the wire format: {e}") from None


def join_records(records: list[bytes], batch_seq: int = 0, dropped_total: int = 0) -> bytes:
    """A state payload from records made by ``pack_record`` (lets a publisher pack as samples arrive)."""
    if not 1 <= len(records) <= MAX_BATCH:
        raise PayloadError(f"a state batch holds 1..{MAX_BATCH} samples, got {len(records)}")
    head = STATE_HEADER.pack(STATE_MAGIC, STATE_VERSION, _KIND_STATE, len(records), STATE_RECORD.size,
                             batch_seq & 0xFFFFFFFF, min(dropped_total, 0xFFFFFFFF))
    return head + b"".join(records)


def encode_state(samples: Iterable[Any], batch_seq: int = 0, dropped_total: int = 0) -> bytes:
    """Pack up to ``MAX_BATCH`` samples behind a version header (``PayloadError`` on bad input)."""
    items = samples if isinstance(samples, list) else list(samples)
    if not 1 <= len(items) <= MAX_BATCH:
        raise PayloadError(f"a state batch holds 1..{MAX_BATCH} samples, got {len(items)}")
    return join_records([pack_record(x) for x in items], batch_seq, dropped_total)


def decode_state(payload: bytes | bytearray | memoryview) -> StateBatch:
    """Unpack a state payload; unknown versions, kinds and truncation raise ``PayloadError``."""
    buf = bytes(payload)
    if len(buf) < STATE_HEADER.size:
        raise PayloadError(f"state payload too short: {len(buf)} bytes < header {STATE_HEADER.size}")
    magic, version, kind, count, rsize, seq, dropped = STATE_HEADER.unpack_from(buf)
    if magic != STATE_MAGIC:
        raise PayloadError(f"not a state payload (magic {magic!r}, expected {STATE_MAGIC!r})")
    if version != STATE_VERSION:
        raise PayloadError(f"state payload version {version}, this decoder reads version {STATE_VERSION}")
    if kind != _KIND_STATE:
        raise PayloadError(f"unknown state payload kind {kind}")
    # a later minor revision may append fields: the record size in the header lets us skip them
    if rsize < STATE_RECORD.size:
        raise PayloadError(f"record size {rsize} smaller than version {version}'s {STATE_RECORD.size}")
    if len(buf) != STATE_HEADER.size + count * rsize:
        raise PayloadError(f"state payload is {len(buf)} bytes, header says {count} x {rsize} + {STATE_HEADER.size}")
    samples = []
    for i in range(count):
        v = STATE_RECORD.unpack_from(buf, STATE_HEADER.size + i * rsize)
        flags, code = v[2], v[-1]
        analog = tuple(v[18:18 + min((flags >> 3) & 3, MAX_ANALOG)])
        samples.append(StateSample(v[0], v[1], bool(flags & 1), *v[3:15], bool(flags & 2), *v[15:18], analog,
                                   v[20], v[21], v[22], bool(flags & 4), v[23], v[24], v[25],
                                   SAFETY_STATES[code] if code < len(SAFETY_STATES) else "unknown"))
    return StateBatch(seq, dropped, samples)


def _finite(obj: Any) -> Any:
    # JSON has no NaN: publish null instead so every subscriber can parse it
    if isinstance(obj, float):
        return obj if math.isfinite(obj) else None
    if isinstance(obj, Mapping):
        return {str(k): _finite(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [_finite(v) for v in obj]
    return obj


def encode_json(kind: str, body: Mapping[str, Any]) -> bytes:
    """A low-rate message: ``{"v": 1, "kind": kind, ...body}`` as UTF-8 JSON (NaN becomes null)."""
    if kind not in JSON_KINDS:
        raise PayloadError(f"unknown message kind {kind!r}; known: {JSON_KINDS}")
    if "v" in body or "kind" in body:
        raise PayloadError("'v' and 'kind' are reserved keys of the envelope")
    return json.dumps({"v": JSON_VERSION, "kind": kind, **_finite(dict(body))}, allow_nan=False,
                      separators=(",", ":"), default=str).encode()


def decode_json(payload: bytes | bytearray | memoryview | str, expect: str | None = None) -> dict[str, Any]:
    """Parse a low-rate message and check its envelope (version, and kind when ``expect`` is given)."""
    try:
        text = payload if isinstance(payload, str) else bytes(payload).decode("utf-8")
        msg = json.loads(text)
    except (UnicodeDecodeError, json.JSONDecodeError) as e:
        raise PayloadError(f"not a JSON telemetry message: {e}") from None
    if not isinstance(msg, dict):
        raise PayloadError(f"a JSON telemetry message is an object, got {type(msg).__name__}")
    if msg.get("v") != JSON_VERSION:
        raise PayloadError(f"JSON message version {msg.get('v')!r}, this decoder reads version {JSON_VERSION}")
    if msg.get("kind") not in JSON_KINDS:
        raise PayloadError(f"unknown message kind {msg.get('kind')!r}")
    if expect is not None and msg["kind"] != expect:
        raise PayloadError(f"expected a {expect!r} message, got {msg['kind']!r}")
    return msg
