"""``SerialHardware``: the rig over pyserial (a USB port, or the pty of a simulated device).

Synchronous and single-threaded on the read side (the loop calls ``read_sample`` each cycle);
writes are serialised by a lock so a supervisor thread may call ``estop``. Frames other than
SAMPLE (ACK, FAULT, HELLO, HEARTBEAT) are consumed as they arrive and kept as state.
"""

from __future__ import annotations

import select
import threading
import time
from collections import OrderedDict, deque

import serial

from rehab_hil.hardware.interface import HardwareError, HardwareInterface, LifecycleState, duty_units
from rehab_hil.protocol import (
    Clear,
    Command,
    Configure,
    DeviceHeartbeat,
    EStop,
    Frame,
    FrameDecoder,
    Heartbeat,
    Hello,
    HelloReq,
    Message,
    Sample,
    SetEncoder,
    encode_frame,
)

__all__ = ["SerialHardware"]

_PENDING_COMMANDS = 1024  # send times kept for latency matching


def _cpr_hint(info: Hello | None, config: Configure) -> str:
    """Why a CONFIGURE may have been refused: a firmware build pinned to another encoder."""
    cpr, dev = config.encoder_counts_per_rev, info.encoder_counts_per_rev if info else 0
    if cpr and dev and cpr != dev:
        return f"; the device reports {dev} encoder counts/rev, the config {cpr} (a build pinned to another encoder?)"
    return ""


class SerialHardware(HardwareInterface):
    """A device speaking protocol v1 on a serial path; see ``HardwareInterface`` for the lifecycle."""

    def __init__(self, port: str, baud: int = 1_000_000, write_timeout_s: float = 0.2) -> None:
        super().__init__()
        self.port, self.baud, self.write_timeout_s = port, baud, write_timeout_s
        self._ser: serial.Serial | None = None
        self._decoder = FrameDecoder()
        self._heartbeats: deque[DeviceHeartbeat] = deque(maxlen=16)
        self._hellos: deque[Hello] = deque(maxlen=16)
        self._sent_at: OrderedDict[int, float] = OrderedDict()  # COMMAND seq -> perf_counter
        self._last_echo: int | None = None
        self._rx_seq: int | None = None
        self._tx_seq = 0
        self._wlock = threading.Lock()

    # ---- lifecycle ----------------------------------------------------------------------------

    def connect(self, timeout: float = 3.0) -> Hello:
        """Open the port, discard stale input, send HELLO_REQ (repeated) until a HELLO arrives."""
        if self.state is LifecycleState.FINALIZED:
            self._require_connected("connect")
        if self._ser is None:
            try:
                self._ser = serial.Serial(self.port, self.baud, timeout=0, write_timeout=self.write_timeout_s)
            except (serial.SerialException, OSError) as e:
                raise HardwareError(f"cannot open {self.port}: {e}") from e
            self._ser.reset_input_buffer()
        self._hellos.clear()
        deadline = time.perf_counter() + timeout
        while time.perf_counter() < deadline:
            self._send(HelloReq())
            resend = min(deadline, time.perf_counter() + 0.25)
            while time.perf_counter() < resend:
                self._pump(resend - time.perf_counter())
                if self._hellos:
                    self.info = self._hellos[-1]
                    self._hellos.clear()
                    if self.state is LifecycleState.UNCONFIGURED:
                        self.state = LifecycleState.INACTIVE
                    return self.info
        raise HardwareError(f"no HELLO from {self.port} within {timeout:.2f} s")

    def configure(self, config: Configure, timeout: float = 1.0) -> None:
        self._require_connected("configure")
        result = self._request(config, timeout)
        if result != 0:
            raise HardwareError(f"device refused CONFIGURE {config} (ACK result {result})"
                                + _cpr_hint(self.info, config))
        self._last_index = None  # the stream restarts: no gap accounting across it
        self.state = LifecycleState.ACTIVE

    def read_sample(self, timeout: float | None = None) -> Sample | None:
        self._require_connected("read_sample")
        deadline = None if timeout is None else time.perf_counter() + timeout
        while not self._samples:
            remaining = 0.5 if deadline is None else deadline - time.perf_counter()
            if remaining <= 0:
                return None
            self._pump(remaining)
        t, sample = self._samples.popleft()
        self.last_sample_time = t
        return sample


    def flush_input(self) -> None:
        """Forget everything received and not yet read: the OS buffer, a partial frame, queued
        samples (after a pause in reading, to start again from fresh data)."""
        ser = self._require()
        try:
            ser.reset_input_buffer()
        except (serial.SerialException, OSError) as e:
            raise HardwareError(f"link to {self.port} lost: {e}") from e
        self._decoder.reset()
        self._samples.clear()
        self._last_index = None

    def write_command(self, duty0: float, duty1: float = 0.0, direction: int = 0, enable: bool = True) -> int:
        self._require_active("write_command")
        return self.send_command(Command(duty_units(duty0), duty_units(duty1), int(direction) & 0xFF,
                                         1 if enable else 0))

    def send_command(self, command: Command) -> int:
        """Send a COMMAND in raw duty units, in any connected state (conformance tests send commands
        before CONFIGURE on purpose); returns its seq (latency is matched on the echo)."""
        seq = self._send(command)
        self._sent_at[seq] = time.perf_counter()
        while len(self._sent_at) > _PENDING_COMMANDS:
            self._sent_at.popitem(last=False)
        return seq

    def estop(self, timeout: float = 1.0) -> None:
        self._require_connected("estop")
        result = self._request(EStop(), timeout)
        if result != 0:
            raise HardwareError(f"ESTOP answered with result {result}")

    def clear(self, timeout: float = 1.0) -> bool:
        self._require_connected("clear")
        return self._request(Clear(), timeout) == 0

    def set_encoder(self, count: int = 0, timeout: float = 1.0) -> None:
        self._require_connected("set_encoder")
        result = self._request(SetEncoder(int(count)), timeout)
        if result != 0:
            raise HardwareError(f"SET_ENCODER {count} answered with result {result}")

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
        ser, self._ser = self._ser, None
        if ser is None:
            return
        try:
            with self._wlock:
                ser.write(encode_frame(Command(0, 0, 0, 0), self._tx_seq))
                self._tx_seq = (self._tx_seq + 1) & 0xFFFF
        except (serial.SerialException, OSError):
            pass
        try:
            ser.close()
        except (serial.SerialException, OSError):
            pass

    # ---- internals ----------------------------------------------------------------------------

    def _require(self) -> serial.Serial:
        if self._ser is None:
            raise HardwareError("not connected")
        return self._ser

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
        ser = self._require()
        try:
            ser.write(data)
        except serial.SerialTimeoutException as e:
            raise HardwareError(f"write to {self.port} timed out (device not reading)") from e
        except (serial.SerialException, OSError) as e:
            raise HardwareError(f"link to {self.port} lost: {e}") from e

    def _request(self, msg: Message, timeout: float) -> int:
        seq = self._send(msg)
        key = (msg.TYPE, seq)
        deadline = time.perf_counter() + timeout
        while key not in self._acks:
            remaining = deadline - time.perf_counter()
            if remaining <= 0:
                raise HardwareError(f"no ACK for {type(msg).__name__} (seq {seq}) within {timeout:.2f} s")
            self._pump(remaining)
        return self._acks.pop(key)

    def _pump(self, timeout: float) -> None:
        """Wait up to ``timeout`` s for bytes, then decode everything available."""
        ser = self._require()
        try:
            if not ser.in_waiting:
                select.select([ser.fileno()], [], [], max(0.0, timeout))
            data = ser.read(ser.in_waiting or 1)
        except (serial.SerialException, OSError, ValueError, TypeError) as e:
            raise HardwareError(f"link to {self.port} lost: {e}") from e
        if not data:
            return
        now = time.perf_counter()
        for frame in self._decoder.feed(data):
            self._handle(frame, now)
        self.stats.bad_frames = +self._decoder.bad  # copy without zero counts

    def _handle(self, frame: Frame, now: float) -> None:
        st, msg = self.stats, frame.msg
        st.frames_rx += 1
        self._rx_seq = frame.seq
        if isinstance(msg, Sample):
            st.device_rx_bad_frames = msg.rx_bad_frames
            if msg.cmd_seq_echo != self._last_echo:
                self._last_echo = msg.cmd_seq_echo
                sent = self._sent_at.get(msg.cmd_seq_echo)
                if sent is not None:
                    st.latencies_s.append(now - sent)
                    while self._sent_at and next(iter(self._sent_at)) != msg.cmd_seq_echo:
                        self._sent_at.popitem(last=False)
                    self._sent_at.popitem(last=False)
            self._received_sample(now, msg)
        elif self._received_reply(msg):
            pass
        elif isinstance(msg, Hello):
            if self.info is not None and frame.seq == 0:  # unsolicited boot HELLO: the device rebooted
                st.reboots += 1
                self._last_index = None
            self._hellos.append(msg)
        elif isinstance(msg, DeviceHeartbeat):
            self._heartbeats.append(msg)
