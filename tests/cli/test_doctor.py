"""``rehab-hil doctor`` against the Python simulated device on a real pty (and the firmware in simavr):
every check passes on a healthy rig with the simulated user moving the plant through the device's
``input`` knob; a noisy force sensor and an open e-stop loop (device fault flags / knobs) fail; on a
plain serial path nobody moves the finger, so the manual steps time out and the exit status is 1.
PWM stays 0 throughout (checked in every sample)."""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

from rehab_hil.cli import main
from rehab_hil.cli.doctor import Hand, SimulatedHand, run_checks, table
from rehab_hil.hardware import SerialHardware
from rehab_hil.loading import load_config
from rehab_hil.plants import get_plant

ROOT = Path(__file__).resolve().parents[2]
FE = ROOT / "configs" / "finger_extensor.toml"


@pytest.fixture
def fe() -> tuple[Any, Any]:
    cfg = load_config(FE)
    return cfg, get_plant(cfg.plant).device(cfg)


def spawn(extra: list[str] | None = None) -> Any:
    from rehab_hil.devices import spawn_device

    return spawn_device("sim", FE, clock="realtime", extra_args=extra)


@pytest.fixture
def device() -> Iterator[Any]:
    with spawn() as dev:
        yield dev


def statuses(rows: list[Any]) -> dict[str, str]:
    return {r.name: r.status for r in rows}


def test_a_healthy_simulated_rig_passes_every_check_then_a_plain_path_times_out(
        device: Any, fe: tuple[Any, Any], capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch) -> None:
    cfg, binding = fe
    monkeypatch.setenv("COLUMNS", "250")  # one table row per line
    hw = SerialHardware(device.port, write_timeout_s=1.0)
    try:
        hw.connect(timeout=10.0)
        rows = run_checks(hw, cfg, binding, SimulatedHand(device, dict(binding.constant_inputs), say=lambda s: None),
                          seconds=0.5, timeout_s=5.0, expected_fw=(1, 1, 0))
    finally:
        hw.close()
    assert set(statuses(rows).values()) == {"PASS"}, rows
    assert {"handshake", "limits accepted", "sample rate / link", "PWM off", "e-stop loop", "faults at rest",
            "encoder moves"} <= set(statuses(rows))
    # the same device as a serial path: nobody moves the finger, the manual steps time out, exit 1
    rc = main(["doctor", "--config", str(FE), "--device", device.port, "--yes", "--seconds", "0.3", "--timeout", "0.5"])
    out = capsys.readouterr().out
    assert rc == 1
    assert "did not move (check A/B wiring, pull-ups, 5 V to the encoder) within 0.5 s" in out
    assert "2 FAILED" in out and "duty 0 in all" in out, out


def test_a_noisy_force_sensor_and_an_open_estop_loop_fail(fe: tuple[Any, Any]) -> None:
    cfg, binding = fe
    with spawn(["--adc-noise-counts", "20"]) as dev:
        dev.control("estop 1")
        hw = SerialHardware(dev.port, write_timeout_s=1.0)
        try:
            hw.connect(timeout=10.0)
            rows = run_checks(hw, cfg, binding, SimulatedHand(dev, dict(binding.constant_inputs), say=lambda s: None),
                              seconds=0.5, timeout_s=2.0)
        finally:
            hw.close()
    st = statuses(rows)
    assert st["e-stop loop"] == "FAIL" and st["A0 (patient_torque_nm) at rest"] == "FAIL"
    assert st["PWM off"] == "PASS" and st["handshake"] == "PASS"
    detail = {r.name: r.detail for r in rows}
    assert "noisy" in detail["A0 (patient_torque_nm) at rest"]
    assert "FAIL" in str(table(rows, "t").columns[1]._cells)


def test_the_simulated_user_skips_what_the_plant_cannot_do() -> None:
    class Device:  # the control channel of a device whose plant has only a supply-voltage input
        def control(self, line: str) -> str:
            raise AssertionError(f"no knob should be turned: {line}")

    hand = SimulatedHand(Device(), {"supply_voltage_v": 32.0}, say=lambda s: None)
    assert not hand.act("move", "move the finger") and not hand.act("press", "press")
    assert Hand(False, say=lambda s: None).act("move", "move the finger")


def test_doctor_on_the_firmware_in_simavr_passes(capsys: pytest.CaptureFixture[str],
                                                monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("COLUMNS", "250")
    from rehab_hil.devices import avr_device

    if avr_device.unavailable_reason():
        pytest.skip(avr_device.unavailable_reason())
    rc = main(["doctor", "--config", str(FE), "--device", "avr", "--yes", "--seconds", "0.5", "--timeout", "5"])
    out = capsys.readouterr().out
    assert rc == 0, out
    assert "FAIL" not in out and "encoder moves" in out
