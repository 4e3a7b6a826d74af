"""Passive wire and tendon excursion (seed 000 eq 5, 10-11)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from rehab_hil.models.passive_wire import PassiveWire, TendonExcursion


def _out(part, u):
    y = np.zeros(len(part.outputs))
    part.output(0.0, np.zeros(0), np.zeros(0), np.asarray(u, float), part.param_values, y)
    return y


def test_excursion_is_the_radius_weighted_sum_of_joint_angles():
    t = TendonExcursion("t", radius1_m=0.01, radius2_m=0.008, radius3_m=0.006)
    assert _out(t, [0.3, 0.4, 0.2, 0.0])[0] == pytest.approx(0.01 * 0.3 + 0.008 * 0.4 + 0.006 * 0.2)


def test_an_exoskeleton_offset_is_spread_with_the_eq9_coupling():
    t = TendonExcursion("t", radius1_m=0.01, radius2_m=0.008, radius3_m=0.006)
    phi = 0.3
    assert _out(t, [0, 0, 0, phi])[0] == pytest.approx(phi / 3 * (0.01 + 1.2 * 0.008 + 0.8 * 0.006))


def test_tension_is_e_m_strain_area_and_zero_when_slack():
    w = PassiveWire("w", martensite_modulus_pa=27e9, radius_m=0.15e-3, length_m=1.8, pretension_n=0.0)
    assert _out(w, [0.018])[0] == pytest.approx(27e9 * 0.01 * math.pi * 0.15e-3**2)
    assert _out(w, [-0.01])[0] == 0.0
