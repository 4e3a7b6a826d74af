"""``SerialPort``: the bytes of one open serial port, through its file descriptor.

pyserial finds, opens and configures the port (baud, raw mode, non-blocking) and flushes it; the
bytes themselves go through the port's file descriptor: one ``poll`` and one ``os.read`` to take
what arrived, one ``os.write`` per frame (pyserial's read and write wrap each in a ``select`` and a
``Timeout`` object, and ``in_waiting`` is an ioctl). Kept apart from ``SerialHardware`` because these
are the link's OS handles, the part of it that does not cross to a loop process: there the port is
taken over from its descriptor (``handed_over``) and the protocol state comes by pickle.
"""

from __future__ import annotations

import math
import os
import select
import time

import serial

from rehab_hil.hardware.interface import HardwareError

__all__ = ["SerialPort"]

_READ_SIZE = 4096  # bytes per read: a burst of ~110 SAMPLEs
_POLLIN = select.POLLIN | select.POLLPRI


class _OpenPort:
    """A port opened by another process and handed over as a file descriptor: what ``SerialPort``
    needs of its pyserial object (the marker that it is open, and ``close``)."""

    def __init__(self, fd: int) -> None:
        self.fd = fd

    def close(self) -> None:
        os.close(self.fd)

    def fileno(self) -> int:
        return self.fd


class SerialPort:
    """An open port: waiting for and taking the bytes that arrived, writing all of a frame. Not
    locked: the caller serialises writes (``SerialHardware`` holds a lock around each frame)."""

    def __init__(self, path: str, ser: serial.Serial | _OpenPort, write_timeout_s: float) -> None:
        self.path, self.ser, self.write_timeout_s = path, ser, write_timeout_s
        self.fd = ser.fileno()  # opened O_NONBLOCK by pyserial
        self._poll = select.poll()
        self._poll.register(self.fd, _POLLIN)

    @classmethod
    def open(cls, path: str, baud: int, write_timeout_s: float) -> SerialPort:
        """Open and configure ``path`` with pyserial, discarding stale input."""
        try:
            ser = serial.Serial(path, baud, timeout=0, write_timeout=write_timeout_s)
        except (serial.SerialException, OSError) as e:
            raise HardwareError(f"cannot open {path}: {e}") from e
        ser.reset_input_buffer()
        return cls(path, ser, write_timeout_s)

    @classmethod
    def handed_over(cls, path: str, fd: int, write_timeout_s: float) -> SerialPort:
        """The port another process opened, from its file descriptor (neither opened nor configured again)."""
        return cls(path, _OpenPort(fd), write_timeout_s)

    def take(self, timeout: float) -> bytes:
        """Wait up to ``timeout`` s for bytes, then take everything available (b"" if none came)."""
        try:
            if timeout >= 0.001:
                ready = bool(self._poll.poll(math.ceil(timeout * 1000.0)))  # ms, rounded up
            else:
                ready = timeout > 0.0 and bool(select.select((self.fd,), (), (), timeout)[0])
            if timeout > 0.0 and not ready:
                return b""
            data = os.read(self.fd, _READ_SIZE)
        except BlockingIOError:  # nothing there
            return b""
        except OSError as e:
            raise HardwareError(f"link to {self.path} lost: {e}") from e
        if not data and ready:  # a raw tty (VMIN 0) reads b"" when empty: only after readiness is it the end
            raise HardwareError(f"link to {self.path} lost: the device end closed")
        return data

    def write(self, data: bytes) -> None:
        """Write all of ``data``: at once when the port takes it (always, at the loop's rate), else
        waiting for room up to the write timeout."""
        try:
            n = os.write(self.fd, data)
        except BlockingIOError:
            n = 0
        except OSError as e:
            raise HardwareError(f"link to {self.path} lost: {e}") from e
        if n < len(data):
            self._write_rest(memoryview(data)[n:])

    def _write_rest(self, data: memoryview) -> None:
        deadline = time.perf_counter() + self.write_timeout_s
        while data:
            remaining = deadline - time.perf_counter()
            try:
                if remaining <= 0 or not select.select([], [self.fd], [], remaining)[1]:
                    raise HardwareError(f"write to {self.path} timed out (device not reading)")
                data = data[os.write(self.fd, data):]
            except BlockingIOError:
                continue
            except (OSError, ValueError) as e:
                raise HardwareError(f"link to {self.path} lost: {e}") from e

    def flush_input(self) -> None:
        """Discard what the OS holds received and not yet taken."""
        try:
            self.ser.reset_input_buffer()
        except (serial.SerialException, OSError) as e:
            raise HardwareError(f"link to {self.path} lost: {e}") from e

    def close(self) -> None:
        """Release the port; a port whose device end is gone may fail to close, which is ignored."""
        try:
            self._poll.unregister(self.fd)
        except (KeyError, ValueError, OSError):
            pass
        try:
            self.ser.close()
        except (serial.SerialException, OSError):
            pass
