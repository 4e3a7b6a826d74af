"""Serial protocol v1 between the host and the rig (docs/protocol.md): messages, framing, decoding.

A frame on the wire is ``COBS(packet) + b"\\x00"``; a packet is
``version:u8 | type:u8 | seq:u16 | payload | crc:u16`` (little-endian, CRC-16/CCITT-FALSE over
everything before the CRC). This module does no I/O: the simulated devices, the host hardware
interface and the tests all build on it.
"""

from __future__ import annotations

import binascii
import operator
import struct
from collections import Counter
from collections.abc import Callable
from dataclasses import dataclass, fields
from typing import Any, ClassVar

from cobs import cobs

__all__ = [
    "BAD_KINDS",
    "BASE_RATE_HZ",
    "DUTY_FULL",
    "MAX_FRAME",
    "MAX_PACKET",
    "MESSAGE_TYPES",
    "PROTOCOL_VERSION",
    "Ack",
    "AckResult",
    "Clear",
    "CommandFrame",
    "Configure",
    "DeviceHeartbeat",
    "EStop",
    "Fault",
    "FaultReport",
    "Frame",
    "FrameDecoder",
    "Heartbeat",
    "Hello",
    "HelloReq",
    "Message",
    "ProtocolError",
    "ResetCause",
    "Sample",
    "SetEncoder",
    "Status",
    "crc16_ccitt_false",
    "decode_packet",
    "encode_command",
    "encode_frame",
    "encode_packet",
    "nearest_rate_divider",
]

PROTOCOL_VERSION = 1
MAX_PACKET = 64  # largest decoded packet [bytes]
MAX_FRAME = MAX_PACKET + 1  # largest COBS-encoded packet, without the 0x00 delimiter [bytes]
HEADER = struct.Struct("<BBH")
CRC = struct.Struct("<H")
MIN_PACKET = HEADER.size + CRC.size  # 6
DUTY_FULL = 10_000  # duty units for a duty of 1.0
BASE_RATE_HZ = 1000  # device base tick; sample rates are BASE_RATE_HZ / k
# kinds of dropped frames, in the order docs/protocol.md lists them
BAD_KINDS = ("cobs", "short", "crc", "version", "type", "length", "overflow")


class Status:
    """Bits of SAMPLE.status."""

    STREAMING = 1 << 0
    PWM_ENABLED = 1 << 1
    FAULT_LATCHED = 1 << 2
    ESTOP_INPUT_ACTIVE = 1 << 3
    DUTY_CLAMPED = 1 << 4
    WATCHDOG_ARMED = 1 << 5


class Fault:
    """Bits of SAMPLE.faults and FAULT.faults / all_faults (latched until CLEAR)."""

    WATCHDOG = 1 << 0
    HEATING_TIME = 1 << 1
    FORCE_LIMIT = 1 << 2
    RANGE_OF_MOTION = 1 << 3
    ESTOP_INPUT = 1 << 4
    ESTOP_COMMAND = 1 << 5
    HW_WATCHDOG_RESET = 1 << 6
    BAD_CONFIG = 1 << 7

    NAMES: ClassVar[dict[int, str]] = {
        1 << 0: "WATCHDOG", 1 << 1: "HEATING_TIME", 1 << 2: "FORCE_LIMIT", 1 << 3: "RANGE_OF_MOTION",
        1 << 4: "ESTOP_INPUT", 1 << 5: "ESTOP_COMMAND", 1 << 6: "HW_WATCHDOG_RESET", 1 << 7: "BAD_CONFIG",
    }

    @staticmethod
    def names(bits: int) -> list[str]:
        """Names of the set fault bits (for logs and error messages)."""
        return [n for b, n in Fault.NAMES.items() if bits & b]


class AckResult:
    """ACK.result values."""

    OK = 0
    REFUSED = 1  # a latched fault remains (CLEAR while its cause is present)
    BAD_PARAMETER = 2  # CONFIGURE with an invalid field


class ResetCause:
    """Bits of HELLO.reset_cause (the AVR's MCUSR)."""

    POWER_ON = 1 << 0
    EXTERNAL = 1 << 1
    BROWN_OUT = 1 << 2
    HW_WATCHDOG = 1 << 3


class ProtocolError(ValueError):
    """A packet that must be dropped; ``kind`` is one of ``BAD_KINDS``."""

    def __init__(self, kind: str, message: str) -> None:
        super().__init__(f"{kind}: {message}")
        self.kind = kind


def crc16_ccitt_false(data: bytes, crc: int = 0xFFFF) -> int:
    """CRC-16/CCITT-FALSE (poly 0x1021, init 0xFFFF, no reflection, xorout 0); b"123456789" -> 0x29B1.

    The standard library's ``binascii.crc_hqx`` is this CRC when seeded with 0xFFFF (in C: ~0.3 us
    for a frame, against ~70 us for a bitwise loop in Python, which mattered at 1 kHz)."""
    return binascii.crc_hqx(data, crc)


@dataclass(frozen=True)
class Message:
    """Base of every message: ``TYPE`` is the type byte, ``FMT`` the struct of the payload."""

    TYPE: ClassVar[int] = -1
    FMT: ClassVar[struct.Struct] = struct.Struct("<")

    def payload(self) -> bytes:
        """The payload bytes; ``struct.error`` if a field is out of its wire range."""
        return self.FMT.pack(*_field_values(type(self))(self))

    @classmethod
    def from_payload(cls, payload: bytes) -> Message:
        return cls(*cls.FMT.unpack(payload))


_FIELD_VALUES: dict[type, Callable[[Any], tuple[Any, ...]]] = {}


def _field_values(cls: type[Message]) -> Callable[[Any], tuple[Any, ...]]:
    """A message's field values in wire order, by one precompiled getter per class (``astuple``
    copies recursively and was most of ``encode_frame``'s cost)."""
    get = _FIELD_VALUES.get(cls)
    if get is None:
        names = [f.name for f in fields(cls)]
        if not names:
            get = lambda m: ()  # noqa: E731
        elif len(names) == 1:
            one = operator.attrgetter(names[0])
            get = lambda m: (one(m),)  # noqa: E731
        else:
            get = operator.attrgetter(*names)
        _FIELD_VALUES[cls] = get
    return get


# ---- host -> device ---------------------------------------------------------------------------

@dataclass(frozen=True)
class HelloReq(Message):
    """Ask for the device's HELLO (capabilities)."""

    TYPE: ClassVar[int] = 0x01


@dataclass(frozen=True)
class Configure(Message):
    """Sample rate (0 = stop streaming), watchdog and safety limits; answered by ACK."""

    TYPE: ClassVar[int] = 0x02
    FMT: ClassVar[struct.Struct] = struct.Struct("<HHHIHiiBBH")
    sample_rate_hz: int
    watchdog_ms: int
    max_duty: int  # duty units (DUTY_FULL = 1.0)
    max_heating_ms: int
    force_limit_counts: int  # A0 counts; 1023 = off
    enc_min: int
    enc_max: int
    flags: int = 0  # bit0: e-stop input pin enabled; bit1: normally-closed loop (pin high = stop)
    force_debounce_ms: int = 1  # FORCE_LIMIT needs this many consecutive ticks above the limit (0 and 1: one)
    # the rig's encoder: the device adopts it and reports it in HELLO; 0 keeps the device's value;
    # a build pinned to one encoder refuses any other (ACK 2)
    encoder_counts_per_rev: int = 0

    FLAG_ESTOP_INPUT: ClassVar[int] = 1 << 0
    FLAG_ESTOP_NORMALLY_CLOSED: ClassVar[int] = 1 << 1


@dataclass(frozen=True)
class CommandFrame(Message):
    """The COMMAND frame: PWM duty per channel, direction bits and enable; applied on arrival, feeds
    the watchdog. (``loop.controllers.Command`` is the loop's command, in duty 0..1.)"""

    TYPE: ClassVar[int] = 0x03
    FMT: ClassVar[struct.Struct] = struct.Struct("<HHBB")
    duty0: int
    duty1: int
    direction: int = 0  # bit k: channel k reversed
    enable: int = 1  # 0: all PWM off


@dataclass(frozen=True)
class Heartbeat(Message):
    """Host link check; the device answers with its own uptime. Does not feed the watchdog."""

    TYPE: ClassVar[int] = 0x04
    FMT: ClassVar[struct.Struct] = struct.Struct("<I")
    uptime_ms: int


@dataclass(frozen=True)
class EStop(Message):
    """Emergency stop: PWM off at once, ESTOP_COMMAND latched; answered by ACK."""

    TYPE: ClassVar[int] = 0x05


@dataclass(frozen=True)
class Clear(Message):
    """Clear latched faults whose cause is gone; ACK result 0 if none remain, else 1."""

    TYPE: ClassVar[int] = 0x06


@dataclass(frozen=True)
class SetEncoder(Message):
    """Set the encoder count to ``count`` (homing: 0 at the home pose); answered by ACK 0. The range
    of motion is checked against the new count from the next tick on."""

    TYPE: ClassVar[int] = 0x07
    FMT: ClassVar[struct.Struct] = struct.Struct("<i")
    count: int


# ---- device -> host ---------------------------------------------------------------------------

@dataclass(frozen=True)
class Hello(Message):
    """Capabilities; answers HELLO_REQ and is sent once, unsolicited, after every boot."""

    TYPE: ClassVar[int] = 0x81
    FMT: ClassVar[struct.Struct] = struct.Struct("<BBBBBBHHBHB")
    protocol_version: int
    fw_major: int
    fw_minor: int
    fw_patch: int
    n_pwm: int
    n_adc: int
    encoder_counts_per_rev: int
    adc_ref_mv: int
    adc_bits: int
    max_rate_hz: int
    reset_cause: int


@dataclass(frozen=True)
class Sample(Message):
    """One sensor frame per sample tick (29-byte payload)."""

    TYPE: ClassVar[int] = 0x82
    FMT: ClassVar[struct.Struct] = struct.Struct("<IIiHHHHBHHHH")
    device_time_us: int
    sample_index: int
    encoder_count: int
    adc0: int
    adc1: int
    duty0: int
    duty1: int
    direction: int
    status: int
    faults: int
    cmd_seq_echo: int
    rx_bad_frames: int


@dataclass(frozen=True)
class FaultReport(Message):
    """Sent once per new trip: the new bits and every latched bit."""

    TYPE: ClassVar[int] = 0x83
    FMT: ClassVar[struct.Struct] = struct.Struct("<HH")
    faults: int
    all_faults: int


@dataclass(frozen=True)
class DeviceHeartbeat(Message):
    """The device's answer to HEARTBEAT."""

    TYPE: ClassVar[int] = 0x84
    FMT: ClassVar[struct.Struct] = struct.Struct("<I")
    uptime_ms: int


@dataclass(frozen=True)
class Ack(Message):
    """Answer to CONFIGURE, ESTOP, CLEAR and SET_ENCODER."""

    TYPE: ClassVar[int] = 0x85
    FMT: ClassVar[struct.Struct] = struct.Struct("<BHB")
    acked_type: int
    acked_seq: int
    result: int


_new = object.__new__


def _sample_of(v: tuple[int, ...]) -> Sample:
    """A ``Sample`` from its 12 wire values without the frozen dataclass's per-field ``__setattr__``
    (the same object ``Sample(*v)`` makes, in half the time: one per sample at 1 kHz)."""
    s = _new(Sample)
    d = s.__dict__
    (d["device_time_us"], d["sample_index"], d["encoder_count"], d["adc0"], d["adc1"], d["duty0"], d["duty1"],
     d["direction"], d["status"], d["faults"], d["cmd_seq_echo"], d["rx_bad_frames"]) = v
    return s


assert _sample_of(tuple(range(12))) == Sample(*range(12))


MESSAGE_TYPES: dict[int, type[Message]] = {
    cls.TYPE: cls for cls in (HelloReq, Configure, CommandFrame, Heartbeat, EStop, Clear, SetEncoder,
                              Hello, Sample, FaultReport, DeviceHeartbeat, Ack)
}
assert all(HEADER.size + c.FMT.size + CRC.size <= MAX_PACKET for c in MESSAGE_TYPES.values())


@dataclass(frozen=True)
class Frame:
    """A decoded packet: its sequence number and message."""

    seq: int
    msg: Message


# The hot path's packets as one struct each (header, payload, CRC): a COMMAND out and a SAMPLE in
# every cycle, packed and unpacked in one call.
_COMMAND_BODY = struct.Struct("<BBH" + CommandFrame.FMT.format.lstrip("<"))
_SAMPLE_PACKET = struct.Struct("<BBH" + Sample.FMT.format.lstrip("<") + "H")
_crc = binascii.crc_hqx
_cobs_encode = cobs.encode


def encode_command(seq: int, duty0: int, duty1: int, direction: int = 0, enable: int = 1) -> bytes:
    """``encode_frame(CommandFrame(duty0, duty1, direction, enable), seq)`` without building the message
    (the loop's one frame per cycle); ``struct.error`` if a field is out of its wire range."""
    body = _COMMAND_BODY.pack(PROTOCOL_VERSION, CommandFrame.TYPE, seq & 0xFFFF, duty0, duty1, direction, enable)
    crc = _crc(body, 0xFFFF)
    return _cobs_encode(body + bytes((crc & 0xFF, crc >> 8))) + b"\x00"


def encode_packet(msg: Message, seq: int) -> bytes:
    """The decoded packet (header, payload, CRC) of ``msg`` with sequence number ``seq`` (mod 65536)."""
    body = HEADER.pack(PROTOCOL_VERSION, msg.TYPE, seq & 0xFFFF) + msg.payload()
    return body + CRC.pack(crc16_ccitt_false(body))


def encode_frame(msg: Message, seq: int) -> bytes:
    """The bytes on the wire: COBS-encoded packet plus the 0x00 delimiter."""
    return cobs.encode(encode_packet(msg, seq)) + b"\x00"


def decode_packet(packet: bytes) -> Frame:
    """Check and parse one decoded packet; raises ``ProtocolError`` with the kind of failure."""
    n = len(packet)
    if n == _SAMPLE_PACKET.size and packet[0] == PROTOCOL_VERSION and packet[1] == Sample.TYPE:  # the common case
        if _crc(packet[:-2], 0xFFFF) != packet[-2] | packet[-1] << 8:
            raise ProtocolError("crc", "checksum mismatch")
        v = _SAMPLE_PACKET.unpack(packet)
        return Frame(v[2], _sample_of(v[3:15]))
    if n < MIN_PACKET:
        raise ProtocolError("short", f"{len(packet)} bytes, need at least {MIN_PACKET}")
    if n > MAX_PACKET:
        raise ProtocolError("overflow", f"{n} bytes, at most {MAX_PACKET}")
    body, (crc,) = packet[:-CRC.size], CRC.unpack(packet[-CRC.size:])
    if crc16_ccitt_false(body) != crc:
        raise ProtocolError("crc", "checksum mismatch")
    version, mtype, seq = HEADER.unpack(body[:HEADER.size])
    if version != PROTOCOL_VERSION:
        raise ProtocolError("version", f"protocol version {version}, expected {PROTOCOL_VERSION}")
    cls = MESSAGE_TYPES.get(mtype)
    if cls is None:
        raise ProtocolError("type", f"unknown message type 0x{mtype:02x}")
    payload = body[HEADER.size:]
    if len(payload) != cls.FMT.size:
        raise ProtocolError("length", f"{cls.__name__} payload {len(payload)} bytes, expected {cls.FMT.size}")
    return Frame(seq, cls.from_payload(payload))


class FrameDecoder:
    """Streaming decoder: ``feed(bytes)`` returns the valid frames completed so far and never raises.

    Bad frames are dropped and counted by kind in ``bad`` (a ``Counter`` over ``BAD_KINDS``);
    bytes beyond ``MAX_FRAME`` without a delimiter are discarded up to the next 0x00 and counted
    once as ``overflow``. Empty frames (consecutive 0x00) are ignored and not counted."""

    def __init__(self) -> None:
        self._buf = bytearray()
        self._overflowed = False
        self.bad: Counter[str] = Counter()
        self.frames = 0  # valid frames decoded

    @property
    def bad_total(self) -> int:
        return sum(self.bad.values())

    def reset(self) -> None:
        """Drop any partial frame (e.g. after reopening the port); counters are kept."""
        self._buf.clear()
        self._overflowed = False

    def feed(self, data: bytes) -> list[Frame]:
        out: list[Frame] = []
        start = 0
        find = data.find
        while True:
            end = find(b"\x00", start)
            if end < 0:
                self._append(data[start:])
                return out
            if self._buf or self._overflowed:  # the end of a frame that began in an earlier chunk
                self._append(data[start:end])
                if not self._overflowed and self._buf:
                    frame = self._decode(bytes(self._buf))
                    if frame is not None:
                        out.append(frame)
                self._buf.clear()
                self._overflowed = False
            elif end - start > MAX_FRAME:  # a whole frame in this chunk (the usual case): no copy to the buffer
                self.bad["overflow"] += 1
            elif end > start:
                frame = self._decode(data[start:end])
                if frame is not None:
                    out.append(frame)
            start = end + 1

    def _append(self, chunk: bytes) -> None:
        """Buffer part of a frame; past ``MAX_FRAME`` bytes it is dropped up to its delimiter."""
        if chunk and not self._overflowed:
            self._buf += chunk
            if len(self._buf) > MAX_FRAME:
                self._overflowed = True
                self._buf.clear()
                self.bad["overflow"] += 1

    def _decode(self, encoded: bytes) -> Frame | None:
        try:
            packet = cobs.decode(encoded)
        except cobs.DecodeError:
            self.bad["cobs"] += 1
            return None
        try:
            frame = decode_packet(packet)
        except ProtocolError as e:
            self.bad[e.kind] += 1
            return None
        self.frames += 1
        return frame


def nearest_rate_divider(sample_rate_hz: int) -> int:
    """Tick divider k for a requested rate (> 0): the device samples at BASE_RATE_HZ / k with
    k = max(1, (1000 + rate // 2) // rate), integer arithmetic, exactly as the firmware does."""
    if sample_rate_hz <= 0:
        raise ValueError("sample_rate_hz must be positive")
    return max(1, (BASE_RATE_HZ + sample_rate_hz // 2) // sample_rate_hz)
