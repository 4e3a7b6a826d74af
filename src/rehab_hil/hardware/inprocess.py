"""``InProcessHardware``: the device's firmware logic (``DeviceCore``) and a plant behind the rig's
I/O, in this process, behind ``HardwareInterface`` (ros2_control's mock components).

Lockstep: while streaming, each accepted COMMAND advances the device one sample period (its base
ticks, each stepping the plant) and so produces the next SAMPLE at once. No pty, no subprocess,
deterministic; the same safety rules as the firmware (watchdog counted in device ticks).
"""

from __future__ import annotations

import dataclasses
import time
from collections.abc import Mapping, Sequence
from typing import Protocol

from rehab_hil.devices.core import DeviceCore, Readings
from rehab_hil.hardware.interface import Arrival, HardwareError, HardwareInterface, LifecycleState, duty_units
from rehab_hil.protocol import (
    CommandFrame,
    Configure,
    Frame,
    Hello,
    HelloReq,
    Message,
    Sample,
)

__all__ = ["InProcessHardware", "PlantPort"]

_ACTIVE = LifecycleState.ACTIVE  # read tests against a module global: ~15 ns; the enum class attribute ~100 ns


class PlantPort(Protocol):
    """What the device reads and drives (``rehab_hil.devices.plant_io.PlantIO``): one base tick
    with the applied duties and direction bits -> (encoder count, adc0, adc1) at the tick instant."""

    def tick(self, duty: tuple[int, int] | list[int], direction: int) -> tuple[int, int, int]: ...

    def start_session(self) -> None:
        """The session starts now (an accepted CONFIGURE): scheduled changes count from here."""


class InProcessHardware(HardwareInterface):
    """A lockstep device in this process; ``hello`` overrides fields of the device's HELLO (e.g.
    ``{"protocol_version": 2}`` or ``{"n_pwm": 1}``) to play a different firmware. ``bursts``: the
    sample periods each COMMAND runs, cycled (``(2, 2, 3)`` delivers samples as the Uno's USB bridge
    does, 2-3 at a time, the host controlling once per burst; deterministically)."""

    def __init__(self, plant: PlantPort, encoder_counts_per_rev: int, *,
                 hello: Mapping[str, int] | None = None, bursts: Sequence[int] = (1,)) -> None:
        super().__init__()
        self.plant = plant
        self.core = DeviceCore(encoder_counts_per_rev)
        self.estop_pin = False  # the e-stop input (True = pressed)
        self._hello_overrides = dict(hello or {})
        unknown = set(self._hello_overrides) - {f.name for f in dataclasses.fields(Hello)}
        if unknown:
            raise ValueError(f"unknown HELLO fields {sorted(unknown)}")
        self._tx_seq = 0
        self._sent: tuple[int, float] | None = None  # the last COMMAND (seq, perf_counter) until echoed
        if not bursts or any(int(b) < 1 for b in bursts):
            raise ValueError(f"bursts must be sample counts >= 1, got {tuple(bursts)}")
        self._bursts = tuple(int(b) for b in bursts)
        self._burst_i = 0

    # ---- lifecycle ----------------------------------------------------------------------------

    def connect(self, timeout: float = 2.0) -> Hello:
        if self.state is LifecycleState.FINALIZED:
            self._require_connected("connect")
        self._send(HelloReq())
        if self.info is None:
            raise HardwareError("the in-process device sent no HELLO")
        if self.state is LifecycleState.UNCONFIGURED:
            self.state = LifecycleState.INACTIVE
        return self.info

    def read(self, timeout: float | None = None) -> Arrival | None:
        """The next queued sample or None at once, whatever ``timeout`` (nothing arrives while the
        host waits in lockstep)."""
        if self.state is not _ACTIVE and not self.state.connected:
            self._require_connected("read")
        samples = self._samples
        return samples.popleft() if samples else None

    def write_command(self, duty0: float, duty1: float = 0.0, direction: int = 0, enable: bool = True) -> int:
        self._require_active("write_command")
        return self._send(CommandFrame(duty_units(duty0), duty_units(duty1), int(direction) & 0xFF, 1 if enable else 0))

    def close(self) -> None:
        """PWM off (as the serial link's last COMMAND does) and FINALIZED; idempotent."""
        if self.state.connected:
            self.core.on_frame(Frame(self._tx_seq, CommandFrame(0, 0, 0, 0)))
        self.state = LifecycleState.FINALIZED

    # ---- the device side ----------------------------------------------------------------------

    def _send(self, msg: Message) -> int:
        """Hand one frame to the device (lockstep: a COMMAND while streaming runs one sample
        period); the device's answers are handled before this returns."""
        seq = self._tx_seq
        self._tx_seq = (seq + 1) & 0xFFFF
        self.stats.frames_tx += 1
        core = self.core
        command = isinstance(msg, CommandFrame)
        if command:
            self._sent = (seq, time.perf_counter())
        self._receive(core.on_frame(Frame(seq, msg)))
        if not command:
            if isinstance(msg, Configure) and core.config is msg:  # accepted: a session starts (scheduled changes)
                self.plant.start_session()
            return seq
        if core.streaming:
            periods = self._bursts[self._burst_i % len(self._bursts)]
            self._burst_i += 1
            plant_tick, core_tick, receive = self.plant.tick, core.tick, self._receive
            for _ in range(core.divider * periods):  # most ticks send nothing: no call to take it
                enc, a0, a1 = plant_tick(core.duty, core.direction)
                out = core_tick(Readings(enc, a0, a1, self.estop_pin))
                if out:
                    receive(out)
        return seq

    def _request(self, msg: Message, timeout: float) -> int:
        """Hand the request to the device and take its ACK, there at once (lockstep: nothing is
        lost or late, so ``timeout`` is not waited on)."""
        seq = self._send(msg)
        result = self._acks.pop((msg.TYPE, seq), None)
        if result is None:
            raise HardwareError(f"no ACK for {type(msg).__name__} (seq {seq})")
        return result

    def _receive(self, msgs: list[Message]) -> None:
        """The host side of the link: what ``SerialHardware`` does with decoded frames."""
        now = time.perf_counter()
        st = self.stats
        for msg in msgs:
            st.frames_rx += 1
            if isinstance(msg, Sample):
                if self._sent is not None and msg.cmd_seq_echo == self._sent[0]:
                    st.latencies_s.append(now - self._sent[1])  # command -> echo: the device's work
                    self._sent = None
                self._received_sample(now, msg)
            elif self._received_reply(msg):
                pass
            elif isinstance(msg, Hello):
                self.info = dataclasses.replace(msg, **self._hello_overrides)
