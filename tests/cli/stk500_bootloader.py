"""A stand-in for the Uno's bootloader (optiboot, STK500v1 subset) on a real pty, so that avrdude can
upload through exactly the command line ``rehab-hil flash`` builds. Only the USB cable and the board
are missing: the bytes avrdude sends go through a real tty and land in an emulated 32 KB flash."""

from __future__ import annotations

import os
import pty
import select
import threading
import tty

OK, INSYNC, EOP = 0x10, 0x14, 0x20
SIGNATURE = bytes([0x1E, 0x95, 0x0F])  # ATmega328P


class Stk500Bootloader:
    """Answers avrdude's STK500v1 requests from a thread; ``flash`` holds what was programmed."""

    def __init__(self) -> None:
        self.master, self.slave = pty.openpty()
        tty.setraw(self.master)
        self.path = os.ttyname(self.slave)
        self.flash = bytearray(b"\xff" * 32768)
        self.written: set[int] = set()  # byte addresses programmed
        self.commands: list[int] = []
        self._buf = bytearray()
        self._address = 0
        self._stop = False
        self._thread = threading.Thread(target=self._serve, daemon=True)
        self._thread.start()

    def _read(self, n: int) -> bytes:
        while len(self._buf) < n:
            if self._stop:
                raise EOFError
            ready, _, _ = select.select([self.master], [], [], 0.05)
            if ready:
                try:
                    self._buf += os.read(self.master, 4096)
                except OSError:  # EIO while nobody has the slave open
                    continue
        out, self._buf = bytes(self._buf[:n]), self._buf[n:]
        return out

    def _reply(self, data: bytes = b"") -> None:
        if self._read(1)[0] != EOP:  # every request ends with Sync_CRC_EOP
            return
        os.write(self.master, bytes([INSYNC]) + data + bytes([OK]))

    def _serve(self) -> None:
        try:
            while True:
                cmd = self._read(1)[0]
                self.commands.append(cmd)
                if cmd == 0x30:  # GET_SYNC
                    self._reply()
                elif cmd == 0x41:  # GET_PARAMETER: optiboot 8.0 reports software version 8.0
                    param = self._read(1)[0]
                    self._reply(bytes([{0x81: 8, 0x82: 0}.get(param, 3)]))
                elif cmd == 0x42:  # SET_DEVICE: 20 parameter bytes, ignored
                    self._read(20)
                    self._reply()
                elif cmd == 0x45:  # SET_DEVICE_EXT: a count byte, then count - 1 bytes, ignored
                    self._read(self._read(1)[0] - 1)
                    self._reply()
                elif cmd in (0x50, 0x51):  # ENTER / LEAVE_PROGMODE
                    self._reply()
                elif cmd == 0x55:  # LOAD_ADDRESS: word address, little-endian
                    lo, hi = self._read(2)
                    self._address = 2 * (lo | hi << 8)
                    self._reply()
                elif cmd == 0x56:  # UNIVERSAL (SPI passthrough): 4 bytes, answer 0
                    self._read(4)
                    self._reply(b"\x00")
                elif cmd == 0x64:  # PROG_PAGE: size (big-endian), memtype, data
                    hi, lo, mem = self._read(3)
                    data = self._read(hi << 8 | lo)
                    if mem == ord("F"):
                        self.flash[self._address:self._address + len(data)] = data
                        self.written.update(range(self._address, self._address + len(data)))
                    self._reply()
                elif cmd == 0x74:  # READ_PAGE
                    hi, lo, mem = self._read(3)
                    n = hi << 8 | lo
                    self._reply(bytes(self.flash[self._address:self._address + n]) if mem == ord("F")
                                else b"\xff" * n)
                elif cmd == 0x75:  # READ_SIGN
                    self._reply(SIGNATURE)
                else:  # resync: optiboot ignores what it does not know until EOP
                    pass
        except EOFError:
            return

    def close(self) -> None:
        self._stop = True
        self._thread.join(timeout=2)
        for fd in (self.master, self.slave):
            try:
                os.close(fd)
            except OSError:
                pass
