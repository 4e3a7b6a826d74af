"""Changes that start mid-session on a simulated rig (issue 23 item 5): PlantIO moves the plant's
parameters, constant inputs and PWM scales on device time, from the session's start (CONFIGURE)."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import pytest

from rehab_hil.devices.plant_io import PlantIO
from rehab_hil.hardware.open import inprocess_hardware
from rehab_hil.loading import load_config
from rehab_hil.plants import get_plant
from rehab_hil.protocol import BASE_RATE_HZ
from rehab_hil.service import assembly
from rehab_hil.testing import CONFIGS, config_with_changes

pytestmark = pytest.mark.slow  # importing the plants pulls in python-control and scipy

FE = CONFIGS / "finger_extensor.toml"
SMA = CONFIGS / "sma_exoskeleton.toml"


def _binding(path: Path) -> Any:
    cfg = load_config(path)
    return get_plant(cfg.plant).device(cfg)


def _drive(plant: PlantIO, ticks: int, duty: int = 3000) -> tuple[list[tuple[int, int, int]], list[np.ndarray]]:
    """Readings and the plant's continuous state after each tick, at a constant duty."""
    readings, states = [], []
    for _ in range(ticks):
        readings.append(plant.tick([duty, 0], 0))
        states.append(plant.stepper.x.copy())
    return readings, states


def test_an_effect_starting_at_half_a_second_changes_nothing_before_and_the_motion_after(tmp_path: Path) -> None:
    path = config_with_changes(FE, tmp_path / "fe.toml", effects=[
        {"name": "constant_load", "params": {"level_nm": 0.4}, "start_s": 0.5}])
    plain, scheduled = PlantIO(_binding(FE)), PlantIO(_binding(path))
    r0, x0 = _drive(plain, 1000)
    r1, x1 = _drive(scheduled, 1000)
    start = round(0.5 * BASE_RATE_HZ)  # the tick whose step first carries the load
    assert r0[:start + 1] == r1[:start + 1]  # every reading up to the start instant, bit for bit
    assert all(np.array_equal(a, b) for a, b in zip(x0[:start], x1[:start], strict=True))
    assert not np.array_equal(x0[start], x1[start])  # the first step with the load moves differently
    assert r1[-1][0] < r0[-1][0] - 20  # a load against the opening: 20+ counts (1.8 deg) less open by 1 s


def test_a_ramp_is_linear_from_its_start_and_the_session_restarts_it(tmp_path: Path) -> None:
    path = config_with_changes(FE, tmp_path / "fe.toml", effects=[
        {"name": "viscous_friction", "params": {"damping_nm_s_per_rad": 0.2}, "start_s": 0.1, "ramp_s": 0.2}])
    binding = _binding(path)
    (item,) = binding.schedule.items
    k = item.param_index[0]
    assert binding.schedule.params[k] == 0.0 and item.param_delta[0] == pytest.approx(0.2)  # off -> params
    plant = PlantIO(binding)

    def damping_after(ticks: int) -> float:
        for _ in range(ticks):
            plant.tick([0, 0], 0)
        return float(plant.stepper.params[k])

    assert damping_after(100) == 0.0  # session ticks 0..99: before start_s
    assert damping_after(101) == pytest.approx(0.1)  # set at session tick 200 = 0.2 s: halfway through the ramp
    assert damping_after(50) == pytest.approx(0.15)  # 0.25 s: three quarters
    assert damping_after(100) == pytest.approx(0.2)  # past the ramp: the end value, and it stays
    plant.start_session()  # a new CONFIGURE: the clock restarts and the value is back at its start
    assert plant.stepper.params[k] == 0.0 and damping_after(151) == pytest.approx(0.05)


def test_a_supply_sag_through_the_pwm_scale_slows_the_motor(tmp_path: Path) -> None:
    path = config_with_changes(FE, tmp_path / "fe.toml", changes=[
        {"key": "motor.supply_v", "scale": 0.92, "start_s": 0.2}])
    binding = _binding(path)
    assert [dict(i.scale_delta) for i in binding.schedule.items] == [{"motor_voltage_v": pytest.approx(-1.92)}]
    r0, _ = _drive(PlantIO(_binding(FE)), 600)
    r1, _ = _drive(PlantIO(binding), 600)
    assert r0[:201] == r1[:201]
    assert r1[-1][0] < r0[-1][0] - 5  # 8 % less voltage: the iris opens less far in the same 0.6 s


def test_sma_contact_stiffness_doubling_and_supply_sag_change_the_plant(tmp_path: Path) -> None:
    """A changed parameter (contact stiffness x2: a stiffer finger on the pad) and a changed constant
    input (supply voltage -8 %: the wire heats slower) on the SMA exoskeleton."""
    stiff = config_with_changes(SMA, tmp_path / "stiff.toml", changes=[
        {"key": "contact.stiffness_n_per_m", "scale": 2.0, "start_s": 0.5}])
    sag = config_with_changes(SMA, tmp_path / "sag.toml", changes=[
        {"key": "drive.supply_voltage_v", "scale": 0.92}])
    b_stiff, b_sag = _binding(stiff), _binding(sag)
    (item,) = b_stiff.schedule.items
    assert item.param_delta == pytest.approx([981.5122] * len(item.param_index))  # every part reading k
    assert dict(b_sag.schedule.items[0].input_delta) == {"supply_voltage_v": pytest.approx(-2.56)}
    plain, p_stiff, p_sag = PlantIO(_binding(SMA)), PlantIO(b_stiff), PlantIO(b_sag)
    plain.tick([0, 0], 0)
    assert plain._u[plain._index["supply_voltage_v"]] == 32.0
    p_sag.tick([0, 0], 0)
    assert p_sag._u[p_sag._index["supply_voltage_v"]] == pytest.approx(29.44)  # from the start
    for _ in range(1500):
        plain.tick([10000, 0], 0)
        p_stiff.tick([10000, 0], 0)
        p_sag.tick([10000, 0], 0)
    temp = [p.stepper.x[p.system.diagram.state_names.index("sma_thermal.temperature_c")] for p in (plain, p_sag)]
    assert temp[1] < temp[0] - 1.0  # (29.44 / 32)^2 = 85 % of the heating power
    assert not np.array_equal(plain.stepper.x, p_stiff.stepper.x)  # the stiffer contact moved the fingers


def test_the_in_process_rig_starts_the_session_clock_at_configure(tmp_path: Path) -> None:
    """Device time before CONFIGURE does not count: the effect starts start_s after the session's start."""
    path = config_with_changes(FE, tmp_path / "fe.toml", effects=[
        {"name": "constant_load", "params": {"level_nm": 0.4}, "start_s": 0.05}])
    cfg = load_config(path)
    binding = get_plant(cfg.plant).device(cfg)
    hw = inprocess_hardware(binding)
    hw.connect()
    plant = hw.plant
    for _ in range(200):  # the device ran 0.2 s since power-on before the host configured it
        plant.tick([0, 0], 0)
    assert plant.session_ticks == 200 and plant._alpha == [1.0]  # from power-on the load would act by now
    hw.configure(assembly.firmware_configure(cfg, binding))
    assert plant.session_ticks == 0 and plant._alpha == [0.0]
    k = binding.schedule.items[0].param_index[0]
    assert plant.stepper.params[k] == 0.0  # back off until 0.05 s into the session


def test_the_python_device_starts_the_session_clock_at_an_accepted_configure(tmp_path: Path) -> None:
    """The simulated device on its pty: a CONFIGURE frame restarts the clock; a refused one does not."""
    import dataclasses

    from rehab_hil.devices.sim_device import SimDevice
    from rehab_hil.protocol import encode_frame

    path = config_with_changes(FE, tmp_path / "fe.toml", effects=[
        {"name": "constant_load", "params": {"level_nm": 0.4}, "start_s": 0.05}])
    cfg = load_config(path)
    binding = get_plant(cfg.plant).device(cfg)
    plant = PlantIO(binding)
    device = SimDevice(plant, 0, clock="lockstep")
    try:
        for _ in range(120):  # 0.12 s of device time since power-on
            device.tick()
        assert plant.session_ticks == 120 and plant._alpha == [1.0]
        good = assembly.firmware_configure(cfg, binding)
        device.on_bytes(encode_frame(dataclasses.replace(good, watchdog_ms=0), 1))  # refused: BAD_PARAMETER
        assert device.core.config is None and plant.session_ticks == 120
        device.on_bytes(encode_frame(good, 2))
        assert device.core.config == good and plant.session_ticks == 0 and plant._alpha == [0.0]
    finally:
        device.close()
