"""The firmware builds with the plain Makefile (Debian's gcc-avr + arduino-core-avr) and fits an
Uno; a test build proves the AVR hardware watchdog resets a hung firmware."""

from __future__ import annotations

import re
import shutil
import subprocess
from collections.abc import Iterator
from pathlib import Path

import pytest

from rehab_hil.protocol import Fault, ResetCause

from .conftest import ROOT, Hardware, Harness, _missing, config, unsolicited_hello

pytestmark = [pytest.mark.firmware, pytest.mark.slow, pytest.mark.timeout(120)]

UNO_FLASH = 32256  # 32 KiB minus the 512 B Optiboot bootloader
UNO_RAM = 2048


def _make(build_dir: Path, *extra: str) -> str:
    if shutil.which("avr-gcc") is None:
        pytest.skip("avr-gcc not installed: run scripts/install_toolchain.sh")
    r = subprocess.run(["make", "-j2", "-C", str(ROOT / "firmware"), f"BUILD={build_dir}", *extra],
                       capture_output=True, text=True, timeout=110)
    assert r.returncode == 0, r.stdout + r.stderr
    return r.stdout


def test_sketch_compiles_and_fits_the_uno(tmp_path: Path) -> None:
    out = _make(tmp_path / "build")
    m = re.search(r"firmware: flash (\d+) B of 32256 .*RAM (\d+) B of 2048", out)
    assert m, out
    flash, ram = int(m.group(1)), int(m.group(2))
    assert 0 < flash < UNO_FLASH and 0 < ram < UNO_RAM * 3 // 4  # leave room for the stack
    assert (tmp_path / "build" / "rehab_fw.hex").stat().st_size > 0
    # independent check of the printed figures
    size = subprocess.run(["avr-size", str(tmp_path / "build" / "rehab_fw.elf")], capture_output=True, text=True)
    text, data, bss = map(int, size.stdout.splitlines()[1].split()[:3])
    assert flash == text + data and ram >= data + bss


@pytest.fixture(scope="module")
def hang_elf(tmp_path_factory: pytest.TempPathFactory) -> Path:
    build = tmp_path_factory.mktemp("fw_test_hooks")
    _make(build, "TEST_HOOKS=1")
    return build / "rehab_fw.elf"


@pytest.fixture
def hang_harness(hang_elf: Path) -> Iterator[Harness]:
    reason = _missing()
    if reason:
        pytest.skip(reason)
    h = Harness(hang_elf)
    try:
        yield h
    finally:
        h.close()


def test_hardware_watchdog_resets_a_hung_firmware(hang_harness: Harness) -> None:
    hw = Hardware(hang_harness.port)
    try:
        hw.connect(timeout=10.0)
        hw.configure(config(sample_rate_hz=100))
        assert hw.read_sample(2.0) is not None
        # Test build only: the e-stop pin low while its input is disabled makes loop() spin forever.
        # (after the reboot the device is unconfigured, so the pin no longer hangs it)
        hang_harness.send("D 4 0")
        boot, seq = unsolicited_hello(hw)
        hang_harness.send("D 4 1")
        assert seq == 0 and boot.reset_cause & ResetCause.HW_WATCHDOG
        assert hang_harness.state()["resets"] == 1
        hw.configure(config(sample_rate_hz=100))
        s = hw.read_sample(2.0)
        assert s is not None and s.faults & Fault.HW_WATCHDOG_RESET
        assert hw.clear()
        hw.discard_pending()  # samples from before the CLEAR (a starved host can hold seconds of them)
        hang_harness.send("E 25")  # the encoder still counts after the reset
        for _ in range(300):
            s = hw.read_sample(2.0)
            if s is None or s.encoder_count == 25:
                break
        assert s is not None and s.encoder_count == 25
    finally:
        hw.close()
