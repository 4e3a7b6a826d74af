"""The firmware's behaviour as a pure state machine (docs/protocol.md, "Behaviour"), without I/O.

``DeviceCore`` takes decoded frames and 1 kHz base ticks with sensor readings and returns the
messages the device sends; it owns the applied PWM outputs and every safety rule (watchdog,
max duty, heating time, force limit, range of motion, e-stop; the checks of a tick and the trip in
devices/safety.py). The Python simulated device wraps it with a pty, a clock and a plant model.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

from rehab_hil.devices.safety import SafetyRules
from rehab_hil.protocol import (
    BASE_RATE_HZ,
    DUTY_FULL,
    PROTOCOL_VERSION,
    Ack,
    AckResult,
    Clear,
    CommandFrame,
    Configure,
    DeviceHeartbeat,
    EStop,
    Fault,
    Frame,
    Heartbeat,
    Hello,
    HelloReq,
    Message,
    ResetCause,
    Sample,
    SetEncoder,
    Status,
    nearest_rate_divider,
)

__all__ = ["FIRMWARE_VERSION", "DeviceCore", "Readings"]

FIRMWARE_VERSION = (1, 1, 0)
TICK_US = 1_000_000 // BASE_RATE_HZ


@dataclass
class Readings:
    """Sensor values at a base tick: encoder count, ADC counts, the e-stop button (True = pressed)
    and whether its wire to D4 is broken; with the rig's wiring they give the pin level (``pin_high``)."""

    encoder_count: int = 0
    adc0: int = 0
    adc1: int = 0
    estop_pin: bool = False
    estop_wire_broken: bool = False

    def pin_high(self, normally_closed: bool) -> bool:
        """D4's level (INPUT_PULLUP): an open circuit reads high. A normally-closed loop holds it low
        until the button opens it; a normally-open button pulls it low when pressed."""
        if self.estop_wire_broken:
            return True
        return self.estop_pin if normally_closed else not self.estop_pin


class DeviceCore(SafetyRules):
    """Protocol v1 device behaviour; ``duty`` / ``direction`` are the applied outputs. The safety
    checks of a tick, ``estop_active`` and the trip are ``SafetyRules`` (devices/safety.py)."""

    def __init__(self, encoder_counts_per_rev: int = 0, reset_cause: int = ResetCause.POWER_ON,
                 estop_normally_closed: bool | None = None) -> None:
        """``encoder_counts_per_rev``: the build's ENCODER_COUNTS_PER_REV; 0 (the default build)
        adopts the value CONFIGURE carries, non-zero pins the device to that encoder (a CONFIGURE
        with another value is refused). ``estop_normally_closed``: how the simulated rig's e-stop is
        wired (from its config's ``[rig.estop]``); None = wired as the host configures it (CONFIGURE
        flags bit1)."""
        self.pinned_counts_per_rev = encoder_counts_per_rev
        self.encoder_counts_per_rev = encoder_counts_per_rev  # reported in HELLO
        self.encoder_offset = 0  # firmware count = the encoder's own edges + this (SET_ENCODER)
        self.reset_cause = reset_cause
        self.estop_wiring_nc = estop_normally_closed
        self.ticks = 0
        self.sample_index = 0
        self.config: Configure | None = None
        self.divider = 0  # sample every `divider` ticks; 0 = not streaming
        self.duty = [0, 0]
        self.direction = 0
        self.enabled = False
        self.clamped = False
        self.faults = 0
        self.armed = False
        self.since_cmd = 0  # base ticks since the last valid COMMAND
        self.heating = 0  # consecutive base ticks with any applied duty > 0
        self.force_ticks = 0  # consecutive base ticks with A0 above the force limit
        self.cmd_seq_echo = 0
        self.rx_bad_frames = 0
        self.readings = Readings()

    # ---- boot ---------------------------------------------------------------------------------

    def boot(self) -> list[Message]:
        """Messages sent once after boot: HELLO, and a FAULT if the hardware watchdog reset us."""
        out: list[Message] = [self.hello()]
        if self.reset_cause & ResetCause.HW_WATCHDOG:
            out += self._trip(Fault.HW_WATCHDOG_RESET)
        return out

    def hello(self) -> Hello:
        major, minor, patch = FIRMWARE_VERSION
        return Hello(PROTOCOL_VERSION, major, minor, patch, 2, 2, self.encoder_counts_per_rev & 0xFFFF,
                     5000, 10, BASE_RATE_HZ, self.reset_cause)

    @property
    def streaming(self) -> bool:
        return self.divider > 0

    # ---- received frames ----------------------------------------------------------------------

    def count_bad_frame(self, n: int = 1) -> None:
        self.rx_bad_frames = (self.rx_bad_frames + n) & 0xFFFF

    def on_frame(self, frame: Frame) -> list[Message]:
        """Handle one valid frame; returns the replies (and FAULT frames of trips it causes)."""
        msg = frame.msg
        if isinstance(msg, CommandFrame):
            self._command(msg, frame.seq)
            return []
        if isinstance(msg, HelloReq):
            return [self.hello()]
        if isinstance(msg, Configure):
            return self._configure(msg, frame.seq)
        if isinstance(msg, Heartbeat):
            return [DeviceHeartbeat(self.uptime_ms)]
        if isinstance(msg, EStop):
            return [*self._trip(Fault.ESTOP_COMMAND), Ack(EStop.TYPE, frame.seq, AckResult.OK)]
        if isinstance(msg, SetEncoder):
            # the count continues from msg.count: the offset moves, the encoder's edges do not
            self.encoder_offset = (self.encoder_offset + msg.count - self.readings.encoder_count) % (1 << 32)
            self.readings = dataclasses.replace(self.readings, encoder_count=msg.count)
            return [Ack(SetEncoder.TYPE, frame.seq, AckResult.OK)]
        if isinstance(msg, Clear):
            self.faults &= self._present_causes()
            result = AckResult.OK if self.faults == 0 else AckResult.REFUSED
            return [Ack(Clear.TYPE, frame.seq, result)]
        self.count_bad_frame()  # a device->host type: unknown to the firmware
        return []

    def _configure(self, c: Configure, seq: int) -> list[Message]:
        cpr, pinned = c.encoder_counts_per_rev, self.pinned_counts_per_rev
        bad = (c.watchdog_ms == 0 or c.max_duty > DUTY_FULL or c.max_heating_ms == 0
               or c.force_limit_counts > 1023 or c.enc_min >= c.enc_max or 0 < cpr < 4
               or (pinned and cpr and cpr != pinned))
        if bad:
            return [*self._trip(Fault.BAD_CONFIG), Ack(Configure.TYPE, seq, AckResult.BAD_PARAMETER)]
        if cpr:
            self.encoder_counts_per_rev = cpr
        self.config = c
        self.divider = 0 if c.sample_rate_hz == 0 else nearest_rate_divider(c.sample_rate_hz)
        self._outputs_off()
        self.clamped = False
        self.armed = False
        self.since_cmd = 0
        return [Ack(Configure.TYPE, seq, AckResult.OK)]

    def _command(self, c: CommandFrame, seq: int) -> None:
        if self.config is None:
            return
        self.since_cmd = 0
        self.armed = True
        if self.faults:
            return
        m = self.config.max_duty
        self.clamped = c.duty0 > m or c.duty1 > m
        if c.enable:
            self.duty = [min(c.duty0, m), min(c.duty1, m)]
            self.direction = c.direction & 0x03
            self.enabled = True
        else:
            self._outputs_off()
        self.cmd_seq_echo = seq

    # ---- time ---------------------------------------------------------------------------------

    @property
    def uptime_ms(self) -> int:
        return (self.ticks * TICK_US // 1000) & 0xFFFFFFFF

    @property
    def device_time_us(self) -> int:
        return (self.ticks * TICK_US) & 0xFFFFFFFF

    def tick(self, readings: Readings, watch_host: bool = True) -> list[Message]:
        """One 1 kHz base tick with the sensor readings of this instant: safety checks, then a
        SAMPLE if this is a sample tick. Returns the FAULT frames of new trips and the SAMPLE.
        ``watch_host=False``: a tick the simulated device catches up after its own process was not
        scheduled while the host's commands arrived; it does not count towards the watchdog (an
        MCU would have seen those commands in time; devices/stall.py)."""
        self.ticks += 1
        if self.encoder_offset:  # the firmware's 32-bit counter, moved by SET_ENCODER
            count = (readings.encoder_count + self.encoder_offset + (1 << 31)) % (1 << 32) - (1 << 31)
            readings = dataclasses.replace(readings, encoder_count=count)
        self.readings = readings
        c = self.config
        out = [] if c is None else self._check_limits(c, watch_host)  # safety first (devices/safety.py)
        if self.divider and self.ticks % self.divider == 0:
            out.append(self.sample())
        return out

    def sample(self) -> Sample:
        """The SAMPLE of the current tick (advances ``sample_index``)."""
        r = self.readings
        s = Sample(self.device_time_us, self.sample_index & 0xFFFFFFFF, r.encoder_count, r.adc0, r.adc1,
                   self.duty[0], self.duty[1], self.direction, self.status, self.faults,
                   self.cmd_seq_echo, self.rx_bad_frames)
        self.sample_index += 1
        return s

    @property
    def status(self) -> int:
        bits = 0
        if self.streaming:
            bits |= Status.STREAMING
        if self.enabled and not self.faults:
            bits |= Status.PWM_ENABLED
        if self.faults:
            bits |= Status.FAULT_LATCHED
        if self.estop_active:
            bits |= Status.ESTOP_INPUT_ACTIVE
        if self.clamped:
            bits |= Status.DUTY_CLAMPED
        if self.armed:
            bits |= Status.WATCHDOG_ARMED
        return bits
