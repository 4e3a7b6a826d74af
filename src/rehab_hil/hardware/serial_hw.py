"""``SerialHardware``: the rig over a serial port (a USB port, or the pty of a simulated device).

pyserial finds, opens and configures the port (baud, raw mode, non-blocking) and flushes it; the
bytes themselves go through the port's file descriptor: one ``poll`` and one ``os.read`` to take
what arrived, one ``os.write`` per frame (pyserial's read and write wrap each in a ``select`` and a
``Timeout`` object, and ``in_waiting`` is an ioctl). Synchronous and single-threaded on the read
side (the loop calls ``read`` each cycle); writes are serialised by a lock so a supervisor
thread may call ``estop``. Frames other than SAMPLE (ACK, FAULT, HELLO, HEARTBEAT) are consumed
as they arrive and kept as state.
"""

from __future__ import annotations

import math
import os
import select
import threading
import time
from collections import deque
from typing import Any

import serial

from rehab_hil.hardware.interface import Arrival, HardwareError, HardwareInterface, LifecycleState, duty_units
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


class _OpenPort:
    """A port opened by another process and handed over as a file descriptor: what ``SerialHardware``
    needs of its pyserial object (the marker that it is open, and ``close``)."""

    def __init__(self, fd: int) -> None:
        self.fd = fd

    def close(self) -> None:
        os.close(self.fd)

    def fileno(self) -> int:
        return self.fd

_ACTIVE = LifecycleState.ACTIVE  # read tests against a module global: ~15 ns; the enum class attribute ~100 ns

_READ_SIZE = 4096  # bytes per read: a burst of ~110 SAMPLEs
# A request (CONFIGURE, CLEAR, ESTOP, SET_ENCODER) not acknowledged this long is sent again, with
# a new seq: a byte lost in the 328P's 2-byte receive buffer (the firmware busy for two byte times;
# tests/firmware/test_bootloader.py) loses the frame, and with it the ACK, for good. The last copy's
# ACK is waited for (until the caller's timeout) before the request returns: the link keeps order,
# so by then every earlier copy was applied or lost, and no late copy can restart the device's
# stream after the caller went on. All four are idempotent.
_RESEND_S = 0.5
_HELLO_RESEND_S = 0.25  # HELLO_REQ is asked again sooner: nothing else can start before it
_POLLIN = select.POLLIN | select.POLLPRI


class SerialHardware(HardwareInterface):
    """A device speaking protocol v1 on a serial path; see ``HardwareInterface`` for the lifecycle."""

    def __init__(self, port: str, baud: int = 1_000_000, write_timeout_s: float = 0.2,
                 resend_s: float | None = _RESEND_S) -> None:
        """``resend_s``: a request not acknowledged this long is sent again (HELLO_REQ: every 0.25 s);
        None: never (a device in virtual time: its pty loses nothing, and a copy sent again enters
        the UART as one more host frame that costs device time, so what the device does would depend
        on how busy the host was: a second HELLO_REQ moved the first COMMAND past a tick)."""
        super().__init__()
        self.port, self.baud, self.write_timeout_s = port, baud, write_timeout_s
        self.resend_s = math.inf if resend_s is None else resend_s
        self._ser: serial.Serial | None = None
        self._fd = -1  # the port's file descriptor while open
        self._poll = select.poll()
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
        if self._ser is None:
            try:
                self._ser = serial.Serial(self.port, self.baud, timeout=0, write_timeout=self.write_timeout_s)
            except (serial.SerialException, OSError) as e:
                raise HardwareError(f"cannot open {self.port}: {e}") from e
            self._ser.reset_input_buffer()
            self._fd = self._ser.fileno()  # opened O_NONBLOCK by pyserial
            self._poll.register(self._fd, _POLLIN)
        self._hellos.clear()
        deadline = time.perf_counter() + timeout
        while time.perf_counter() < deadline:
            self._send(HelloReq())
            again_s = _HELLO_RESEND_S if math.isfinite(self.resend_s) else math.inf
            resend = min(deadline, time.perf_counter() + again_s)
            while time.perf_counter() < resend:
                self._pump(resend - time.perf_counter())
                if self._hellos:
                    self.info = self._hellos[-1]
                    self._hellos.clear()
                    if self.state is LifecycleState.UNCONFIGURED:
                        self.state = LifecycleState.INACTIVE
                    return self.info
        raise HardwareError(f"no HELLO from {self.port} within {timeout:.2f} s")

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
        ser = self._require()
        try:
            ser.reset_input_buffer()
        except (serial.SerialException, OSError) as e:
            raise HardwareError(f"link to {self.port} lost: {e}") from e
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
        if self._ser is None:
            return
        try:
            self._send(CommandFrame(0, 0, 0, 0))
        except HardwareError:
            pass
        ser, self._ser = self._ser, None
        try:
            self._poll.unregister(self._fd)
        except (KeyError, ValueError, OSError):
            pass
        self._fd = -1
        try:
            ser.close()
        except (serial.SerialException, OSError):
            pass

    # ---- crossing to a loop process ------------------------------------------------------------

    @classmethod
    def handed_over(cls, state: dict[str, Any], fd: int) -> SerialHardware:
        """The link a session's process handed to a loop process (``loop.process``): its state
        (``link_state``) and the port's file descriptor, passed to the process as it was started, so the
        port is neither opened again (an Arduino's reset) nor closed; the session's copy stays open beside
        it, idle while the loop process runs."""
        hw = cls.__new__(cls)
        hw.__dict__.update(state)
        hw._fd = fd
        hw._ser = _OpenPort(fd)
        hw._poll = select.poll()
        hw._poll.register(fd, _POLLIN)
        hw._wlock = threading.Lock()
        hw.stats.bad_frames = hw._decoder.bad
        return hw

    @property
    def fd(self) -> int:
        """The open port's file descriptor (-1 when closed)."""
        return self._fd

    def link_state(self) -> dict[str, Any]:
        """What the link knows besides its OS handles: counters, sequence numbers, the lifecycle state,
        queued samples and a partly decoded frame (``adopt_link_state`` takes it back after a run)."""
        skip = ("_ser", "_fd", "_poll", "_wlock", "device_process")
        return {k: v for k, v in self.__dict__.items() if k not in skip}

    def close_handed(self) -> None:
        """A loop process's end: release its copy of the handed-over port, sending nothing (the session's
        copy goes on)."""
        ser, self._ser = self._ser, None
        if ser is not None:
            ser.close()
        self._fd = -1
        self.state = LifecycleState.FINALIZED

    def adopt_link_state(self, state: dict[str, Any]) -> None:
        """Go on where a loop process's copy of this link stopped (its bytes were read there)."""
        self.__dict__.update({k: v for k, v in state.items() if k not in ("_ser", "_fd", "_poll", "_wlock")})
        self.stats.bad_frames = self._decoder.bad

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
        """Write all of ``data``: at once when the port takes it (always, at the loop's rate), else
        waiting for room up to the write timeout."""
        if self._ser is None:
            raise HardwareError("not connected")
        try:
            n = os.write(self._fd, data)
        except BlockingIOError:
            n = 0
        except OSError as e:
            raise HardwareError(f"link to {self.port} lost: {e}") from e
        if n < len(data):
            self._write_rest(memoryview(data)[n:])

    def _write_rest(self, data: memoryview) -> None:
        deadline = time.perf_counter() + self.write_timeout_s
        while data:
            remaining = deadline - time.perf_counter()
            try:
                if remaining <= 0 or not select.select([], [self._fd], [], remaining)[1]:
                    raise HardwareError(f"write to {self.port} timed out (device not reading)")
                data = data[os.write(self._fd, data):]
            except BlockingIOError:
                continue
            except (OSError, ValueError) as e:
                raise HardwareError(f"link to {self.port} lost: {e}") from e

    def _request(self, msg: Message, timeout: float) -> int:
        """Send ``msg`` and return its first ACK's result: sent again every ``resend_s`` while no
        copy is acknowledged. The link keeps order, so the last copy's ACK says every copy has been
        applied or lost; until it comes (or ``timeout``), a copy may still be on its way to restart
        what the caller goes on to do."""
        deadline = time.perf_counter() + timeout
        seqs: list[int] = []
        result: int | None = None
        last_answered = False
        resend_at = 0.0
        while True:
            now = time.perf_counter()
            for seq in seqs:
                got = self._acks.pop((msg.TYPE, seq), None)
                if got is not None:
                    result = got if result is None else result
                    last_answered = last_answered or seq == seqs[-1]
            if result is not None and (last_answered or now >= deadline):
                self.stats.request_resends += len(seqs) - 1
                return result
            if now >= deadline:
                raise HardwareError(f"no ACK for {type(msg).__name__} (seq {', '.join(map(str, seqs))}) "
                                    f"within {timeout:.2f} s")
            if result is None and now >= resend_at:
                seqs.append(self._send(msg))
                resend_at = now + self.resend_s
            self._pump(min(deadline, resend_at if result is None else deadline) - now)

    def _pump(self, timeout: float) -> None:
        """Wait up to ``timeout`` s for bytes, then decode everything available."""
        if self._ser is None:
            raise HardwareError("not connected")
        try:
            if timeout >= 0.001:
                ready = bool(self._poll.poll(math.ceil(timeout * 1000.0)))  # ms, rounded up
            else:
                ready = timeout > 0.0 and bool(select.select((self._fd,), (), (), timeout)[0])
            if timeout > 0.0 and not ready:
                return
            data = os.read(self._fd, _READ_SIZE)
        except BlockingIOError:  # nothing there
            return
        except OSError as e:
            raise HardwareError(f"link to {self.port} lost: {e}") from e
        if not data:  # a raw tty (VMIN 0) reads b"" when empty: only after readiness is it the end
            if ready:
                raise HardwareError(f"link to {self.port} lost: the device end closed")
            return
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
