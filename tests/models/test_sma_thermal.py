"""SMA electro-thermal model (seed 000 eq 12-13): steady state equals the analytic heat balance."""

from __future__ import annotations

import math

import pytest

from rehab_hil.models.sma_thermal import SMAThermal, steady_temperature_c, wire_geometry
from rehab_hil.models.system import Diagram

# Tables 2 and 5 of seed 000
WIRE = dict(radius_m=0.15e-3, length_m=1.8, density_kg_m3=6500.0, resistivity_ohm_m=0.32e-6)
HEAT = dict(specific_heat_j_per_kg_c=870.0, h1_w_per_m2_c=300.0, h2_w_per_m2_c3=0.02, ambient_c=23.0)


def test_wire_geometry_follows_the_round_wire_formulas():
    m, r, a = wire_geometry(**WIRE)
    section = math.pi * 0.15e-3**2
    assert m == pytest.approx(6500.0 * section * 1.8)
    assert r == pytest.approx(0.32e-6 * 1.8 / section)
    assert a == pytest.approx(2 * math.pi * 0.15e-3 * 1.8)


@pytest.mark.parametrize("duty", [0.4, 1.0])
def test_simulated_steady_state_satisfies_the_analytic_balance(duty):
    """After 15 s (>10 time constants) U^2 tau / R = h(T) A (T - T0) to 1e-6 of the power."""
    sys = Diagram([SMAThermal.from_wire("w", **WIRE, **HEAT)], inputs=("duty", "voltage_v")).compile(1e-3, 1)
    res = sys.simulate(15000, inputs={"duty": duty, "voltage_v": 32.0}, outputs=["temperature_c"])
    t_end = res["temperature_c"][-1]
    _, r_ohm, area = wire_geometry(**WIRE)
    power = 32.0**2 / r_ohm * duty
    loss = (300.0 + 0.02 * t_end**2) * area * (t_end - 23.0)
    assert loss == pytest.approx(power, rel=1e-6)
    assert t_end == pytest.approx(
        steady_temperature_c(duty, 32.0, 0.15e-3, 1.8, 0.32e-6, 300.0, 0.02, 23.0), abs=1e-4)


def test_zero_duty_keeps_the_wire_at_ambient_and_duty_is_clipped_to_one():
    sys = Diagram([SMAThermal.from_wire("w", **WIRE, **HEAT)], inputs=("duty", "voltage_v")).compile(1e-3, 1)
    cold = sys.simulate(2000, inputs={"duty": 0.0, "voltage_v": 32.0}, outputs=["temperature_c"])
    assert cold["temperature_c"][-1] == pytest.approx(23.0, abs=1e-12)
    over = sys.simulate(2000, inputs={"duty": 3.0, "voltage_v": 32.0}, outputs=["temperature_c"])
    full = sys.simulate(2000, inputs={"duty": 1.0, "voltage_v": 32.0}, outputs=["temperature_c"])
    assert over["temperature_c"][-1] == pytest.approx(full["temperature_c"][-1], rel=1e-12)
