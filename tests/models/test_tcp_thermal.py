"""Lumped-capacitance TCP thermal part (seed 001 eq 1a): heat balance and steady state."""

from __future__ import annotations

import numpy as np
import pytest

from rehab_hil.models.tcp_thermal import LumpedThermal

P = np.array([1.465e-4, 1699.3, 15.0, 8.574e-4, 25.0])  # m, c_p, h, A_c, T_inf
E = np.zeros(0)


def test_temperature_rise_follows_the_heat_balance():
    dx = np.zeros(1)
    LumpedThermal.derivatives(0.0, np.array([40.0]), E, np.array([34.0]), P, dx)
    m, cp, h, area, _ = P
    assert dx[0] == pytest.approx((34.0 - h * area * 40.0) / (m * cp))


def test_power_balancing_convection_holds_the_temperature_and_output_adds_ambient():
    _, _, h, area, ambient = P
    rise = 10.0 / (h * area)
    dx, y = np.zeros(1), np.zeros(2)
    LumpedThermal.derivatives(0.0, np.array([rise]), E, np.array([10.0]), P, dx)
    LumpedThermal.output(0.0, np.array([rise]), E, np.array([10.0]), P, y)
    assert dx[0] == pytest.approx(0.0, abs=1e-9)
    assert y[0] == pytest.approx(ambient + rise) and y[1] == pytest.approx(rise)
