"""Finding the rig's serial port: list USB serial ports, name the likely Arduino, resolve
``--device auto``, and say at start which device a session uses.

Classification is by USB vendor id (pyserial's ``serial.tools.list_ports``): Arduino's own boards
(0x2341, 0x2A03), CH340 clones (0x1A86) and FTDI adapters (0x0403). ``/dev/serial/by-id/...``
links are suggested because they survive re-plugging (``/dev/ttyACM0`` may become ``ttyACM1``).
"""

from __future__ import annotations

import os
import sys
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from rehab_hil.hardware.interface import HardwareError

__all__ = ["BY_ID_DIR", "SIMULATED", "USB_KINDS", "PortCandidate", "announce_device", "by_id_path",
           "candidates", "check_device_name", "classify", "describe_device", "resolve_device"]

BY_ID_DIR = Path("/dev/serial/by-id")
SIMULATED = ("sim", "avr", "inprocess")  # open_rig's simulated backends

# USB vendor id -> (kind, rank); a lower rank is a likelier Uno
USB_KINDS: dict[int, tuple[str, int]] = {
    0x2341: ("Arduino", 0),  # arduino.cc (Uno R3: 0x0043, R4: 0x0069 ...)
    0x2A03: ("Arduino", 0),  # arduino.org
    0x1A86: ("CH340 clone", 1),  # WCH CH340/CH341: most Uno clones
    0x0403: ("FTDI", 2),  # FT232R: older boards, USB-serial adapters
}


@dataclass(frozen=True)
class PortCandidate:
    """One serial port as the user sees it, with our guess of what it is."""

    device: str  # /dev/ttyACM0
    by_id: str | None  # /dev/serial/by-id/usb-Arduino__www.arduino.cc__0043_...-if00, when present
    vid: int | None
    pid: int | None
    serial_number: str | None
    description: str
    kind: str | None  # "Arduino", "CH340 clone", "FTDI" or None (not a board we know)
    rank: int  # 0 Arduino, 1 CH340, 2 FTDI, 9 other

    @property
    def likely_arduino(self) -> bool:
        return self.kind is not None

    @property
    def usb_id(self) -> str:
        return f"{self.vid:04x}:{self.pid:04x}" if self.vid is not None and self.pid is not None else "-"

    @property
    def suggested(self) -> str:
        """The path to put in ``[rig].port`` or ``--device``: the stable by-id link if there is one."""
        return self.by_id or self.device


def classify(info: Any) -> tuple[str | None, int]:
    """(kind, rank) of a pyserial ``ListPortInfo`` by its USB vendor id; (None, 9) if unknown."""
    kind = USB_KINDS.get(info.vid) if info.vid is not None else None
    return kind if kind else (None, 9)


def by_id_path(device: str, by_id_dir: Path = BY_ID_DIR) -> str | None:
    """The ``/dev/serial/by-id`` link that points at ``device``, or None."""
    try:
        links = sorted(by_id_dir.iterdir())
    except OSError:
        return None
    target = os.path.realpath(device)
    return next((str(p) for p in links if os.path.realpath(p) == target), None)


def candidates(ports: Iterable[Any] | None = None, by_id_dir: Path = BY_ID_DIR) -> list[PortCandidate]:
    """Every serial port (``ports``: ListPortInfo objects, default the system's), likeliest Uno first."""
    if ports is None:
        from serial.tools import list_ports

        ports = list_ports.comports()
    out = []
    for p in ports:
        kind, rank = classify(p)
        out.append(PortCandidate(p.device, by_id_path(p.device, by_id_dir), p.vid, p.pid, p.serial_number,
                                 p.description or "", kind, rank))
    return sorted(out, key=lambda c: (c.rank, c.device))


def check_device_name(device: str) -> str:
    """``device`` unchanged, unless it is a near-miss of a simulated backend or ``auto`` (``simm``,
    ``AVR``) and no such file exists: that is a typo, not a serial path, and ``HardwareError``
    suggests the name (a serial path is opened only to fail later with "no such port")."""
    import difflib

    names = (*SIMULATED, "auto")
    if device in names or "/" in device or "\\" in device or os.path.exists(device):
        return device
    close = difflib.get_close_matches(device.lower(), names, n=1, cutoff=0.6)
    if device.lower() in names or close:
        suggestion = device.lower() if device.lower() in names else close[0]
        raise HardwareError(f"device {device!r} is none of {', '.join(names)} and no serial path; did you mean "
                            f"{suggestion!r}?")
    return device


def resolve_device(device: str, ports: Iterable[Any] | None = None, by_id_dir: Path = BY_ID_DIR) -> str:
    """``auto`` -> the one likeliest Arduino's port (by-id link when present); a near-miss of a backend
    name is refused (``check_device_name``); anything else unchanged. No Arduino-like port, or
    several equally likely ones, raise ``HardwareError`` saying what to do."""
    if device != "auto":
        return check_device_name(device)
    found = [c for c in candidates(ports, by_id_dir) if c.likely_arduino]
    if not found:
        return _no_arduino(candidates(ports, by_id_dir) if ports is not None else None)
    best = [c for c in found if c.rank == found[0].rank]
    if len(best) > 1:
        listed = ", ".join(f"{c.suggested} ({c.kind} {c.usb_id})" for c in best)
        raise HardwareError(f"{len(best)} boards look like an Arduino: {listed}; pass one with "
                            "--device PATH")
    return best[0].suggested


def _no_arduino(seen: Sequence[PortCandidate] | None) -> str:
    if seen is None:
        seen = candidates()
    others = f" (serial ports present: {', '.join(c.device for c in seen)})" if seen else " (no serial ports at all)"
    raise HardwareError("no Arduino found: no USB serial port with vendor id 2341/2a03 (Arduino), "
                        f"1a86 (CH340) or 0403 (FTDI){others}; plug the board in, check `rehab-hil ports`, "
                        "or give its path (or sim)")


def describe_device(device: str, config_path: str | Path, rig_port: str,
                    ports: Iterable[Any] | None = None) -> tuple[str, list[str]]:
    """(the line saying which device a session uses, warnings). Warns when a config whose ``[rig].port``
    names a real rig runs on a simulated device, and when the simulator runs while a board is plugged in."""
    kinds = {"sim": "the Python simulated device (nothing on the bench moves)",
             "avr": "the firmware in simavr (nothing on the bench moves)",
             "inprocess": "the in-process simulated device (nothing on the bench moves)"}
    line = f"device: {device}: {kinds.get(device, 'a real serial port')} [config {config_path}]"
    warnings: list[str] = []
    if device in SIMULATED:
        if rig_port not in SIMULATED:
            warnings.append(f"warning: {config_path} is for a real rig ([rig].port = {rig_port!r}) but the device "
                            f"is {device!r}: this is a simulation")
        try:
            boards = [c for c in candidates(ports) if c.likely_arduino]
        except Exception:  # listing ports is advisory here; never stop a session for it
            boards = []
        if boards:
            warnings.append(f"warning: {boards[0].kind} connected at {boards[0].suggested}, but the device is "
                            f"{device!r}; pass --device auto (or the path) to use the board")
    return line, warnings


def announce_device(device: str, config_path: str | Path, rig_port: str,
                    write: Callable[[str], Any] | None = None) -> None:
    """Print ``describe_device``'s line and warnings (default: to stderr)."""
    line, warnings = describe_device(device, config_path, rig_port)
    out = write or (lambda s: print(s, file=sys.stderr, flush=True))
    for s in (line, *warnings):
        out(s)
