"""Telemetry payloads, versioned: batched binary state records for 1 kHz samples, JSON for the rest.

The schema is docs/telemetry.md ("Payloads"); this module is its only implementation, so
subscribers decode with ``decode_state`` / ``decode_json`` and never re-implement the layout.
"""

from __future__ import annotations

import json
import math
import struct
from collections.abc import Iterable, Mapping
from typing import Any, NamedTuple

__all__ = [
    "JSON_KINDS",
    "JSON_VERSION",
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
    "to_state_sample",
]

STATE_VERSION = 1
JSON_VERSION = 1
STATE_MAGIC = b"RS"
# magic:2s, version:u8, kind:u8 (1 = state batch), count:u16, record_size:u16,
# batch_seq:u32 (publisher's batch counter), dropped_total:u32 (samples the publisher dropped so far)
STATE_HEADER = struct.Struct("<2sBBHHII")
_KIND_STATE = 1
# host_time_s:f64 | the protocol SAMPLE fields (docs/protocol.md) | angle_deg, force_n, temperature_c,
# setpoint_deg: f32 | safety:u8 (index into SAFETY_STATES)
STATE_RECORD = struct.Struct("<d" + "IIiHHHHBHHHH" + "ffff" + "B")
MAX_BATCH = 1000
SAFETY_STATES = ("unknown", "ok", "warning", "tripped", "estop", "link_lost")
JSON_KINDS = ("stats", "safety", "info", "command")

_RAW = ("device_time_us", "sample_index", "encoder_count", "adc0", "adc1", "duty0", "duty1",
        "direction", "status", "faults", "cmd_seq_echo", "rx_bad_frames")
_DERIVED = ("angle_deg", "force_n", "temperature_c", "setpoint_deg")


class PayloadError(ValueError):
    """A payload that is not a telemetry message this version understands."""


class StateSample(NamedTuple):
    """One loop cycle as published: host time, the raw device SAMPLE, derived SI values, safety."""

    host_time_s: float
    device_time_us: int
    sample_index: int
    encoder_count: int
    adc0: int
    adc1: int
    duty0: int  # duty units, protocol.DUTY_FULL = 1.0
    duty1: int
    direction: int
    status: int
    faults: int
    cmd_seq_echo: int
    rx_bad_frames: int
    angle_deg: float  # NaN when the publisher did not know it
    force_n: float
    temperature_c: float
    setpoint_deg: float
    safety: str


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

    Accepts a ``StateSample``, a ``protocol.Sample``, or any object/mapping with the raw SAMPLE fields
    (directly or under ``.sample``) plus optional ``host_time_s``, derived SI values and ``safety``."""
    if isinstance(obj, StateSample):
        return obj
    raw = _get(obj, "sample", None) or obj
    missing = [f for f in _RAW if _get(raw, f, None) is None]
    if missing:
        raise PayloadError(f"{type(obj).__name__} lacks SAMPLE fields {missing}")
    safety = _get(obj, "safety", "unknown")
    safety = getattr(safety, "value", safety)  # an Enum is fine
    host_t = _get(obj, "host_time_s", None)
    if host_t is None:
        host_t = _get(obj, "t_host_s", math.nan)
    return StateSample(float(host_t), *(int(_get(raw, f, 0)) for f in _RAW),
                       *(float(_get(obj, f, math.nan)) for f in _DERIVED), str(safety))


def encode_state(samples: Iterable[Any], batch_seq: int = 0, dropped_total: int = 0) -> bytes:
    """Pack up to ``MAX_BATCH`` samples behind a version header (``PayloadError`` on bad input)."""
    recs = [to_state_sample(s) for s in samples]
    if not 1 <= len(recs) <= MAX_BATCH:
        raise PayloadError(f"a state batch holds 1..{MAX_BATCH} samples, got {len(recs)}")
    out = bytearray(STATE_HEADER.pack(STATE_MAGIC, STATE_VERSION, _KIND_STATE, len(recs), STATE_RECORD.size,
                                      batch_seq & 0xFFFFFFFF, min(dropped_total, 0xFFFFFFFF)))
    for r in recs:
        try:
            code = SAFETY_STATES.index(r.safety)
        except ValueError:
            code = 0
        try:
            out += STATE_RECORD.pack(r.host_time_s, *r[1:13], *r[13:17], code)
        except struct.error as e:
            raise PayloadError(f"sample {r.sample_index}: field out of range for the wire format: {e}") from None
    return bytes(out)


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
        vals = STATE_RECORD.unpack_from(buf, STATE_HEADER.size + i * rsize)
        code = vals[-1]
        samples.append(StateSample(*vals[:-1], SAFETY_STATES[code] if code < len(SAFETY_STATES) else "unknown"))
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
