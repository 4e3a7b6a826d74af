"""PlantIO: PWM duty and direction into the plant, encoder and ADC counts out, bad bindings refused."""

from __future__ import annotations

import dataclasses
from typing import Any

import pytest

from rehab_hil.devices.plant_io import PlantIO
from rehab_hil.loading import load_config
from rehab_hil.plants import get_plant

from .conftest import CONFIG

pytestmark = pytest.mark.slow  # importing the plants pulls in python-control and scipy


@pytest.fixture(scope="module")
def binding() -> Any:
    cfg = load_config(CONFIG)
    return get_plant(cfg.plant).device(cfg)


def _run(plant: PlantIO, duty: int, direction: int, ticks: int) -> tuple[int, int, int]:
    for _ in range(ticks):
        r = plant.tick([duty, 0], direction)
    return r


def test_at_rest_the_counts_are_the_sensor_offsets(binding: Any) -> None:
    enc, adc0, adc1 = _run(PlantIO(binding), 0, 0, 10)
    assert (enc, adc0, adc1) == (0, round(binding.adc[0].offset_counts), 0)


def test_the_direction_bit_reverses_a_signed_h_bridge(binding: Any) -> None:
    forward, _, _ = _run(PlantIO(binding), 3000, 0b00, 200)
    backward, _, _ = _run(PlantIO(binding), 3000, 0b01, 200)
    assert forward > 20 and backward < -20
    assert abs(forward + backward) <= 2  # the same motion mirrored (within a count of quantisation)


def test_adc_counts_are_clipped_to_ten_bits(binding: Any) -> None:
    plant = PlantIO(binding)
    plant.set_input("patient_torque_nm", 10.0)  # A0 measures the patient's torque: 10 N m is beyond its range
    adcs = [plant.tick([10000, 0], 0)[1] for _ in range(50)]
    assert max(adcs) == 1023


def test_the_torque_sensor_reads_the_patient_torque_input(binding: Any) -> None:
    plant = PlantIO(binding)
    ch = binding.adc[0]
    assert ch.signal == "patient_torque_nm"
    plant.set_input("patient_torque_nm", -1.5)
    assert plant.tick([0, 0], 0)[1] == round(ch.offset_counts - 1.5 * ch.counts_per_unit)


def test_noise_is_seeded_and_reproducible(binding: Any) -> None:
    runs = [[p.tick([0, 0], 0)[1] for _ in range(30)] for p in
            (PlantIO(binding, adc_noise_counts=3.0, seed=1), PlantIO(binding, adc_noise_counts=3.0, seed=1))]
    assert runs[0] == runs[1] and len(set(runs[0])) > 1


@pytest.mark.parametrize(("change", "match"), [
    (dict(step_s=0.0003), "divide"),
    (dict(constant_inputs={}), "patient_torque_nm"),
    (dict(sums=()), "signal 'drive_torque_nm' is produced by parts 'motor', 'rotor_viscous'"),  # sums dropped
])
def test_a_binding_that_cannot_run_on_the_device_is_refused(binding: Any, change: dict, match: str) -> None:
    with pytest.raises(ValueError, match=match):
        PlantIO(dataclasses.replace(binding, **change))


def test_negative_noise_is_refused(binding: Any) -> None:
    with pytest.raises(ValueError, match="adc_noise_counts"):
        PlantIO(binding, adc_noise_counts=-1.0)


def test_unknown_plant_input_is_refused(binding: Any) -> None:
    with pytest.raises(KeyError, match="unknown plant input"):
        PlantIO(binding).set_input("no_such_input", 1.0)
