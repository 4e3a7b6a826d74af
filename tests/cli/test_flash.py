"""``rehab-hil flash``: the exact avrdude command line; avrdude itself uploading the built image over a
real pty to a stand-in for the Uno's bootloader (``stk500_bootloader.py``: the STK500v1 requests
optiboot answers) and verifying it; the handshake check against the real firmware in simavr; the
sketch's compile-time RX-buffer check. The real upload (USB cable, a board's optiboot, the DTR
reset) cannot run here: nothing in these tests proves that a physical Uno takes the image."""

from __future__ import annotations

import shutil
import subprocess
from pathlib import Path

import pytest

from rehab_hil.cli import main
from rehab_hil.cli.flash import HEX, SKETCH, FlashError, avrdude_command, expected_firmware_version, verify_handshake

from .stk500_bootloader import Stk500Bootloader

ROOT = Path(__file__).resolve().parents[2]
ARDUINO = Path("/usr/share/arduino/hardware/arduino/avr")
needs_avrdude = pytest.mark.skipif(shutil.which("avrdude") is None or not HEX.exists(),
                                   reason="avrdude or firmware/build/rehab_fw.hex missing (make toolchain firmware)")


def intel_hex(path: Path) -> dict[int, int]:
    """Address -> byte of an Intel HEX file (data records, extended linear addresses)."""
    out: dict[int, int] = {}
    base = 0
    for line in path.read_text().split():
        raw = bytes.fromhex(line[1:])
        n, addr, kind, data = raw[0], raw[1] << 8 | raw[2], raw[3], raw[4:4 + raw[0]]
        assert sum(raw) & 0xFF == 0 and len(data) == n
        if kind == 0:
            out.update({base + addr + i: b for i, b in enumerate(data)})
        elif kind == 4:
            base = (data[0] << 8 | data[1]) << 16
    return out


def test_the_avrdude_command_line_is_the_uno_bootloader_upload() -> None:
    assert avrdude_command("/dev/serial/by-id/usb-Arduino-if00", Path("/x/rehab_fw.hex")) == [
        "avrdude", "-p", "atmega328p", "-c", "arduino", "-P", "/dev/serial/by-id/usb-Arduino-if00", "-b", "115200",
        "-D", "-U", "flash:w:/x/rehab_fw.hex:i"]


def test_print_command_and_a_simulated_port_is_refused(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["flash", "--port", "/dev/ttyACM0", "--print-command"]) == 0
    assert capsys.readouterr().out.strip() == f"avrdude -p atmega328p -c arduino -P /dev/ttyACM0 -b 115200 -D -U " \
                                              f"flash:w:{HEX}:i"
    assert main(["flash", "--port", "sim"]) == 2
    assert "cannot be flashed" in capsys.readouterr().err


@needs_avrdude
def test_avrdude_writes_and_verifies_the_built_image_through_the_bootloader_protocol() -> None:
    boot = Stk500Bootloader()
    try:
        proc = subprocess.run(avrdude_command(boot.path, HEX), capture_output=True, text=True, timeout=60)
    finally:
        boot.close()
    assert proc.returncode == 0, proc.stderr
    assert "flash verified" in proc.stderr
    image = intel_hex(HEX)
    assert image and all(boot.flash[a] == b for a, b in image.items())
    assert 0x75 in boot.commands  # the signature was checked (ATmega328P)


@needs_avrdude
def test_flash_uploads_then_fails_the_handshake_when_no_firmware_answers(capsys: pytest.CaptureFixture[str]) -> None:
    """The stand-in is only a bootloader: after the upload nothing speaks protocol v1, and flash says so."""
    boot = Stk500Bootloader()
    try:
        rc = main(["flash", "--port", boot.path, "--no-build", "--handshake-timeout", "0.5"])
    finally:
        boot.close()
    err = capsys.readouterr().err
    assert rc == 2 and "uploaded, but the handshake failed: no HELLO" in err
    assert all(boot.flash[a] == b for a, b in intel_hex(HEX).items())


def test_the_handshake_accepts_the_built_firmware_and_refuses_another_version() -> None:
    """The firmware ELF built from the sketch, in simavr, answers with the sketch's FW_* version."""
    from rehab_hil.devices import avr_device, spawn_device

    if avr_device.unavailable_reason():
        pytest.skip(avr_device.unavailable_reason())
    expected = expected_firmware_version()
    with spawn_device("avr", ROOT / "configs" / "finger_extensor.toml") as dev:
        assert "firmware " + ".".join(map(str, expected)) in verify_handshake(dev.port, 1_000_000, expected, 10.0)
        with pytest.raises(FlashError, match=r"expected protocol v1 firmware 9\.9\.9"):
            verify_handshake(dev.port, 1_000_000, (9, 9, 9), 10.0)


@pytest.mark.skipif(shutil.which("avr-g++") is None or not ARDUINO.exists(), reason="AVR toolchain missing")
def test_the_sketch_refuses_a_64_byte_serial_receive_buffer(tmp_path: Path) -> None:
    assert SKETCH.read_text().count('#include "rx_buffer_check.h"') == 1
    unit = tmp_path / "unit.cpp"
    unit.write_text('#include "rx_buffer_check.h"\n')

    def compile_with(defs: list[str]) -> subprocess.CompletedProcess[str]:
        return subprocess.run(["avr-g++", "-mmcu=atmega328p", "-DF_CPU=16000000L", "-DARDUINO=10819", "-Os",
                               "-std=gnu++11", *defs, f"-I{ARDUINO}/cores/arduino", f"-I{ARDUINO}/variants/standard",
                               f"-I{SKETCH.parent}", "-include", "Arduino.h", "-fsyntax-only", str(unit)],
                              capture_output=True, text=True)

    assert compile_with(["-DSERIAL_RX_BUFFER_SIZE=256"]).returncode == 0
    ide = compile_with([])  # what the Arduino IDE does: the core's default, 64 bytes
    assert ide.returncode != 0 and "serial RX buffer must be 256 bytes" in ide.stderr
    assert compile_with(["-DSERIAL_RX_BUFFER_SIZE=512"]).returncode != 0
