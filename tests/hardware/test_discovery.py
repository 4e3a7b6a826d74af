"""Port discovery: classification on pyserial ``ListPortInfo`` objects built here (a pty is not a USB
device, so USB ids cannot come from a real port on this machine), by-id links resolved on real
symlinks, ``auto`` on real ptys, and the device announcement of ``open_rig``."""

from __future__ import annotations

import os
import pty
from pathlib import Path

import pytest
from serial.tools.list_ports_common import ListPortInfo

from rehab_hil.hardware import HardwareError
from rehab_hil.hardware.discovery import by_id_path, candidates, classify, describe_device, resolve_device

ROOT = Path(__file__).resolve().parents[2]


def port(device: str, vid: int | None = None, pid: int | None = None, serial: str | None = None,
         description: str = "n/a") -> ListPortInfo:
    info = ListPortInfo(device, skip_link_detection=True)
    info.vid, info.pid, info.serial_number, info.description = vid, pid, serial, description
    return info


@pytest.fixture
def pty_path() -> str:
    master, slave = pty.openpty()
    yield os.ttyname(slave)
    os.close(master)
    os.close(slave)


@pytest.mark.parametrize(("vid", "kind"), [(0x2341, "Arduino"), (0x2A03, "Arduino"), (0x1A86, "CH340 clone"),
                                           (0x0403, "FTDI"), (0x10C4, None), (None, None)])
def test_vendor_ids_name_the_board(vid: int | None, kind: str | None) -> None:
    assert classify(port("/dev/ttyX", vid, 0x0043))[0] == kind


def test_by_id_link_is_suggested_and_the_genuine_arduino_ranks_first(tmp_path: Path, pty_path: str) -> None:
    link = tmp_path / "usb-Arduino__www.arduino.cc__0043_7563-if00"
    link.symlink_to(pty_path)
    assert by_id_path(pty_path, tmp_path) == str(link)
    found = candidates([port("/dev/ttyUSB0", 0x1A86, 0x7523), port(pty_path, 0x2341, 0x0043, "7563"),
                        port("/dev/ttyS0")], by_id_dir=tmp_path)
    assert [c.device for c in found] == [pty_path, "/dev/ttyUSB0", "/dev/ttyS0"]
    assert found[0].suggested == str(link) and found[0].usb_id == "2341:0043"
    assert found[1].suggested == "/dev/ttyUSB0"  # no by-id link: the plain path
    assert resolve_device("auto", [port(pty_path, 0x2341, 0x0043), port("/dev/ttyUSB0", 0x1A86, 0x7523)],
                          by_id_dir=tmp_path) == str(link)


def test_auto_without_an_arduino_is_a_clear_error(pty_path: str) -> None:
    with pytest.raises(HardwareError, match="no Arduino found.*vendor id 2341.*ports present: " + pty_path):
        resolve_device("auto", [port(pty_path)])
    with pytest.raises(HardwareError, match="no serial ports at all"):
        resolve_device("auto", [])


def test_auto_refuses_to_guess_between_two_boards() -> None:
    with pytest.raises(HardwareError, match=r"2 boards look like an Arduino.*--device PATH"):
        resolve_device("auto", [port("/dev/ttyACM0", 0x2341, 0x43), port("/dev/ttyACM1", 0x2341, 0x43)])


def test_non_auto_devices_pass_through(pty_path: str) -> None:
    for d in ("sim", "avr", "inprocess", pty_path):
        assert resolve_device(d, []) == d


@pytest.mark.parametrize(("typed", "meant"), [("simm", "sim"), ("SIM", "sim"), ("avrr", "avr"),
                                              ("inproces", "inprocess"), ("atuo", "auto")])
def test_a_near_miss_of_a_backend_name_is_refused_with_the_name_meant(typed, meant):
    with pytest.raises(HardwareError, match=f"device '{typed}' is none of .* did you mean '{meant}'"):
        resolve_device(typed, [])


def test_a_serial_name_unlike_any_backend_passes_through():
    for d in ("COM3", "ttyACM0", "/dev/does-not-exist"):
        assert resolve_device(d, []) == d


def test_a_real_rig_config_on_the_simulator_is_warned_about() -> None:
    line, warns = describe_device("sim", "configs/bench.toml", "/dev/ttyACM0", ports=[])
    assert "simulated" in line and "nothing on the bench moves" in line
    assert warns == ["warning: configs/bench.toml is for a real rig ([rig].port = '/dev/ttyACM0') but the device "
                     "is 'sim': this is a simulation"]
    _, warns = describe_device("sim", "c.toml", "sim", ports=[port("/dev/ttyACM0", 0x2341, 0x43)])
    assert len(warns) == 1 and "Arduino connected at /dev/ttyACM0" in warns[0]
    line, warns = describe_device("/dev/ttyACM0", "c.toml", "sim", ports=[])
    assert "real serial port" in line and warns == []


def test_run_with_device_auto_and_no_board_exits_2_with_one_line(capsys: pytest.CaptureFixture[str]) -> None:
    from rehab_hil.cli import main

    rc = main(["run", "--config", str(ROOT / "configs" / "finger_extensor.toml"), "--device", "auto",
               "--duration", "1", "--no-display"])
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == 2 and len(err) == 1 and "no Arduino found" in err[0]


def test_ports_command_lists_or_says_none(capsys: pytest.CaptureFixture[str]) -> None:
    from rehab_hil.cli import main

    rc = main(["ports"])
    out = capsys.readouterr().out
    assert (rc == 0 and "serial ports" in out) or (rc == 1 and "no serial ports found" in out)
