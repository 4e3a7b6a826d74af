"""``rehab-hil flash [--port P]``: build the firmware, upload it to the Uno with avrdude, and check by
handshake that the expected firmware and protocol version answer.

Build: ``make firmware`` (firmware/Makefile: the 256-byte serial RX buffer the protocol needs; the
sketch refuses to compile without it, firmware/rehab_fw/rx_buffer_check.h). Upload: avrdude
through the Uno's bootloader (STK500v1, ``-c arduino``, 115200 baud), which the board enters when
the port is opened (DTR resets it). Port: ``--port``, default ``auto`` (``rehab-hil ports``).
Handshake: after the upload the board boots the new firmware; its HELLO must carry protocol
version ``rehab_hil.protocol.PROTOCOL_VERSION`` and the FW_MAJOR/MINOR/PATCH of the sketch.
"""

from __future__ import annotations

import argparse
import re
import shutil
import subprocess
import time
from pathlib import Path

from rehab_hil.cli import UserError

ROOT = Path(__file__).resolve().parents[3]
SKETCH = ROOT / "firmware" / "rehab_fw" / "rehab_fw.ino"
HEX = ROOT / "firmware" / "build" / "rehab_fw.hex"
PART = "atmega328p"
PROGRAMMER = "arduino"  # the Uno's optiboot speaks STK500v1
BOOTLOADER_BAUD = 115200  # optiboot on the Uno (the IDE's upload.speed)


class FlashError(UserError):
    """Building, uploading or the handshake after the upload failed; printed as one line."""


def add_parser(sub: argparse._SubParsersAction) -> argparse.ArgumentParser:
    p = sub.add_parser("flash", help="build the firmware, upload it with avrdude and check its handshake")
    p.add_argument("--port", default="auto", help="the Uno's serial port (default: auto, see `rehab-hil ports`)")
    p.add_argument("--hex", type=Path, default=HEX, help="the image to upload (default: the one make builds)")
    p.add_argument("--no-build", action="store_true", help="upload --hex as it is (no make firmware)")
    p.add_argument("--baud", type=int, default=1_000_000, help="protocol baud for the handshake [bit/s]")
    p.add_argument("--programmer", default=PROGRAMMER, help="avrdude programmer (-c); default arduino")
    p.add_argument("--upload-baud", type=int, default=BOOTLOADER_BAUD, help="bootloader baud (-b)")
    p.add_argument("--print-command", action="store_true", help="print the avrdude command and do nothing")
    p.add_argument("--handshake-timeout", type=float, default=5.0, help="wait this long for HELLO [s]")
    return p


def expected_firmware_version(sketch: Path = SKETCH) -> tuple[int, int, int]:
    """FW_MAJOR, FW_MINOR, FW_PATCH as #defined in the sketch (what the HELLO must report)."""
    text = sketch.read_text()
    parts = []
    for name in ("FW_MAJOR", "FW_MINOR", "FW_PATCH"):
        m = re.search(rf"^#define {name} (\d+)\s*$", text, re.MULTILINE)
        if not m:
            raise FlashError(f"{sketch}: no '#define {name} <n>'")
        parts.append(int(m.group(1)))
    return parts[0], parts[1], parts[2]


def avrdude_command(port: str, hex_path: Path, *, programmer: str = PROGRAMMER, baud: int = BOOTLOADER_BAUD,
                    part: str = PART, avrdude: str = "avrdude") -> list[str]:
    """The avrdude call that writes ``hex_path`` through the bootloader and verifies it (-D: the
    bootloader erases each page itself, as the Arduino IDE does)."""
    return [avrdude, "-p", part, "-c", programmer, "-P", port, "-b", str(baud), "-D",
            "-U", f"flash:w:{hex_path}:i"]


def build_firmware() -> None:
    """``make firmware`` (toolchain check, then firmware/Makefile); FlashError with make's last lines."""
    proc = subprocess.run(["make", "-s", "firmware"], cwd=ROOT, capture_output=True, text=True)
    if proc.returncode != 0:
        tail = " | ".join((proc.stderr or proc.stdout).strip().splitlines()[-3:])
        raise FlashError(f"make firmware failed ({proc.returncode}): {tail}")


def upload(command: list[str], timeout_s: float = 120.0) -> str:
    """Run avrdude; returns its output, FlashError with its last lines when it fails."""
    if shutil.which(command[0]) is None:
        raise FlashError(f"{command[0]} not found: run `make toolchain` (as root) or apt-get install avrdude")
    try:
        proc = subprocess.run(command, capture_output=True, text=True, timeout=timeout_s)
    except subprocess.TimeoutExpired:
        raise FlashError(f"avrdude did not finish within {timeout_s:.0f} s") from None
    out = proc.stdout + proc.stderr
    if proc.returncode != 0:
        tail = " | ".join(line.strip() for line in out.strip().splitlines()[-3:])
        raise FlashError(f"avrdude failed ({proc.returncode}): {tail}")
    return out


def verify_handshake(port: str, baud: int, expected_fw: tuple[int, int, int], timeout_s: float = 5.0) -> str:
    """Connect with protocol v1 and check the HELLO's protocol and firmware versions; returns a
    one-line description of what answered."""
    from rehab_hil.hardware import HardwareError, SerialHardware
    from rehab_hil.protocol import PROTOCOL_VERSION

    hw = SerialHardware(port, baud)
    try:
        hello = hw.connect(timeout=timeout_s)
    except HardwareError as e:
        raise FlashError(f"uploaded, but the handshake failed: {e}") from None
    finally:
        hw.close()
    fw = (hello.fw_major, hello.fw_minor, hello.fw_patch)
    if hello.protocol_version != PROTOCOL_VERSION or fw != expected_fw:
        raise FlashError(f"{port} answers protocol v{hello.protocol_version} firmware {'.'.join(map(str, fw))}; "
                         f"expected protocol v{PROTOCOL_VERSION} firmware {'.'.join(map(str, expected_fw))}")
    return (f"{port}: protocol v{hello.protocol_version}, firmware {'.'.join(map(str, fw))}, "
            f"encoder {hello.encoder_counts_per_rev} counts/rev")


def run(args: argparse.Namespace) -> int:
    from rehab_hil.hardware import HardwareError
    from rehab_hil.hardware.discovery import resolve_device

    if args.port in ("sim", "avr", "inprocess"):
        raise FlashError(f"--port {args.port}: a simulated device cannot be flashed (its firmware is the build)")
    try:
        port = resolve_device(args.port)
    except HardwareError as e:
        raise FlashError(f"--port {args.port}: {e}") from None
    command = avrdude_command(port, args.hex, programmer=args.programmer, baud=args.upload_baud)
    if args.print_command:
        print(" ".join(command))
        return 0
    if not args.no_build:
        build_firmware()
    if not args.hex.exists():
        raise FlashError(f"{args.hex}: no such image (run make firmware)")
    expected = expected_firmware_version()
    print(f"flash: uploading {args.hex} to {port}: {' '.join(command)}", flush=True)
    upload(command)
    time.sleep(0.5)  # the bootloader jumps to the new firmware; its boot HELLO follows
    print("flash: ok, " + verify_handshake(port, args.baud, expected, args.handshake_timeout))
    return 0
