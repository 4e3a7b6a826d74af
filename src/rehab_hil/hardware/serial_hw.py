"""``SerialHardware``: the rig over a serial port (a USB port, or the pty of a simulated device).

The port's bytes go through ``SerialPort`` (serial_port.py: its file descriptor, poll, read and
write); requests and the handshake are asked again by ``asking.py``; the link crosses to a loop
process by ``LinkHandover`` (handover.py). Synchronous and single-threaded on the read side (the loop
calls ``read`` each cycle); writes are serialised by a lock so a supervisor thread may call
``estop``. Frames other than SAMPLE (ACK, FAULT, HELLO, HEARTBEAT) are consumed as they arrive and
kept as state.
"""

from __future__ import annotations

import math
import threading
import time
from collections import deque

import serial

from rehab_hil.hardware import asking
from rehab_hil.hardware.handover import LinkHandover
from rehab_hil.hardware.interface import Arrival, HardwareError, HardwareInterface, LifecycleState, duty_units
from rehab_hil.hardware.serial_port import SerialPort
from rehab_hil.protocol import (
    CommandFrame,
    DeviceHeartbeat,
    Frame,
    FrameDecoder,
    Heartbeat,
    Hello,
    HelloReq,
    Message,
    Sample,
    encode_command,
    encode_frame,
)

__all__ = ["SerialHardware"]

_ACTIVE = LifecycleState.ACTIVE  # read tests against a module global: ~15 ns; the enum class attribute ~100 ns


class SerialHardware(HardwareInterface, LinkHandover):
    """A device speaking protocol v1 on a serial path; see ``HardwareInterface`` for the lifecycle, and
    ``LinkHandover`` for how the link crosses to a loop process (``handed_over``, ``link_state``)."""

    def __init__(self, port: str, baud: int = 1_000_000, write_timeout_s: float = 0.2,
                 resend_s: float | None = asking.RESEND_S) -> None:
        """``resend_s``: a request not acknowledged this long is sent again (HELLO_REQ: every 0.25 s);
        None: never (a device in virtual time: its pty loses nothing, and a copy sent again enters
        the UART as one more host frame that costs device time, so what the device does would depend
        on how busy the host was: a second HELLO_REQ moved the first COMMAND past a tick)."""
        super().__init__()
        self.port, self.baud, self.write_timeout_s = port, baud, write_timeout_s
        self.resend_s = math.inf if resend_s is None else resend_s
        self._port: SerialPort | None = None  # while open
        self._decoder = FrameDecoder()
        self.stats.bad_frames = self._decoder.bad  # the decoder's own counter (never a zero count): no copy
        self._heartbeats: deque[DeviceHeartbeat] = deque(maxlen=16)
        self._hellos: deque[Hello] = deque(maxlen=16)
        self._sent_at = [0.0] * 0x10000  # COMMAND seq -> perf_counter when sent, 0.0 once echoed
        self._last_echo = -1
        self._tx_seq = 0
        self._wlock = threading.Lock()

    # ---- lifecycle ----------------------------------------------------------------------------

    def connect(self, timeout: float = 3.0) -> Hello:
        """Open the port, discard stale input, send HELLO_REQ (every 0.25 s; once if ``resend_s`` is None)
        until a HELLO arrives."""
        if self.state is LifecycleState.FINALIZED:
            self._require_connected("connect")
        if self._port is None:
            self._port = SerialPort.open(self.port, self.baud, self.write_timeout_s)
        self._hellos.clear()
        info = asking.hello(lambda: self._send(HelloReq()), self._pump, self._hellos, timeout, self.resend_s)
        if info is None:
            raise HardwareError(f"no HELLO from {self.port} within {timeout:.2f} s")
        self.info = info
        self._hellos.clear()
        if self.state is LifecycleState.UNCONFIGURED:
            self.state = LifecycleState.INACTIVE
        return info

    def read(self, timeout: float | None = None) -> Arrival | None:
        """A queued sample at once (one state test and a popleft: the loop's path); else the link is
        read until one arrives or ``timeout`` passes (0: what the OS holds now)."""
        if self.state is not _ACTIVE and not self.state.connected:
            self._require_connected("read")
        samples = self._samples
        if not samples:
            if timeout is not None and timeout <= 0:
                self._pump(0.0)
            else:
                deadline = None if timeout is None else time.perf_counter() + timeout
                while not samples:
                    remaining = 0.5 if deadline is None else deadline - time.perf_counter()
                    if remaining <= 0:
                        break
                    self._pump(remaining)
            if not samples:
                return None
        return samples.popleft()

    def flush_input(self) -> None:
        """Forget everything received and not yet read: the OS buffer, a partial frame, queued
        samples (after a pause in reading, to start again from fresh data)."""
        port = self._port
        if port is None:
            raise HardwareError("not connected")
        port.flush_input()
        self._decoder.reset()
        self._samples.clear()
        self._last_index = None

    def write_command(self, duty0: float, duty1: float = 0.0, direction: int = 0, enable: bool = True) -> int:
        if self.state is not LifecycleState.ACTIVE:
            self._require_active("write_command")
        with self._wlock:
            seq = self._tx_seq
            self._write_locked(encode_command(seq, duty_units(duty0), duty_units(duty1), int(direction) & 0xFF,
                                              1 if enable else 0))
            self._tx_seq = (seq + 1) & 0xFFFF
            self.stats.frames_tx += 1
        self._sent_at[seq] = time.perf_counter()
        return seq

    def send_command(self, command: CommandFrame) -> int:
        """Send a COMMAND in raw duty units, in any connected state (conformance tests send commands
        before CONFIGURE on purpose); returns its seq (latency is matched on the echo)."""
        seq = self._send(command)
        self._sent_at[seq] = time.perf_counter()
        return seq

    def heartbeat(self, timeout: float = 1.0) -> int:
        """Link check: the device's uptime in ms."""
        self._heartbeats.clear()
        self._send(Heartbeat(int(time.monotonic() * 1000) & 0xFFFFFFFF))
        deadline = time.perf_counter() + timeout
        while not self._heartbeats:
            if time.perf_counter() >= deadline:
                raise HardwareError(f"no HEARTBEAT answer within {timeout:.2f} s")
            self._pump(deadline - time.perf_counter())
        return self._heartbeats[-1].uptime_ms

    def send_raw(self, data: bytes) -> None:
        """Write bytes as they are (tests and fault injection: garbage, truncated frames)."""
        self._write(data)

    def close(self) -> None:
        self.state = LifecycleState.FINALIZED
        if self._port is None:
            return
        try:
            self._send(CommandFrame(0, 0, 0, 0))
        except HardwareError:
            pass
        port, self._port = self._port, None
        port.close()

    # ---- internals ----------------------------------------------------------------------------

    def _require(self) -> serial.Serial:
        """The open port's pyserial object (tests read the raw link through it)."""
        if self._port is None:
            raise HardwareError("not connected")
        return self._port.ser

    def _send(self, msg: Message) -> int:
        with self._wlock:
            seq = self._tx_seq
            self._tx_seq = (seq + 1) & 0xFFFF
            self._write_locked(encode_frame(msg, seq))
            self.stats.frames_tx += 1
        return seq

    def _write(self, data: bytes) -> None:
        with self._wlock:
            self._write_locked(data)

    def _write_locked(self, data: bytes) -> None:
        port = self._port
        if port is None:
            raise HardwareError("not connected")
        port.write(data)

    def _request(self, msg: Message, timeout: float) -> int:
        """Send ``msg`` and return its first ACK's result, sent again every ``resend_s`` while no copy
        is acknowledged (``asking.acked``)."""
        result, copies = asking.acked(msg, timeout, self.resend_s, self._send, self._pump, self._acks)
        self.stats.request_resends += copies - 1
        return result

    def _pump(self, timeout: float) -> None:
        """Wait up to ``timeout`` s for bytes, then decode everything available."""
        port = self._port
        if port is None:
            raise HardwareError("not connected")
        data = port.take(timeout)
        if data:
            now = time.perf_counter()
            for frame in self._decoder.feed(data):
                self._handle(frame, now)

    def _handle(self, frame: Frame, now: float) -> None:
        st, msg = self.stats, frame.msg
        st.frames_rx += 1
        if type(msg) is Sample:
            st.device_rx_bad_frames = msg.rx_bad_frames
            echo = msg.cmd_seq_echo
            if echo != self._last_echo:
                self._last_echo = echo
                sent = self._sent_at[echo & 0xFFFF]
                if sent:
                    st.latencies_s.append(now - sent)
                    self._sent_at[echo & 0xFFFF] = 0.0
            self._received_sample(now, msg)
        elif self._received_reply(msg):
            pass
        elif isinstance(msg, Hello):
            if self.info is not None and frame.seq == 0:  # unsolicited boot HELLO: the device rebooted
                self._rebooted("unsolicited HELLO (device restarted)")
            self._hellos.append(msg)
        elif isinstance(msg, DeviceHeartbeat):
            self._heartbeats.append(msg)
