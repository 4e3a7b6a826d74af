"""Hill passive muscle of the long extensor (seed 000 eq 1-3, Table 1)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from rehab_hil.models.hill_muscle import HillPassiveMuscle, paper_literal_force_n, passive_length_factor

YOUNG = dict(max_isometric_force_n=16.05, optimal_fibre_length_m=0.07, rest_length_ratio=1.0, k_pe=5.0, e_o=0.6,
             moment_arm1_m=0.0086, moment_arm2_m=0.005, moment_arm3_m=0.003)


def _out(part, q):
    y = np.zeros(4)
    part.output(0.0, np.zeros(0), np.zeros(0), np.asarray(q, float), part.param_values, y)
    return y


def test_no_passive_force_at_or_below_optimal_length():
    assert passive_length_factor(1.0, 5.0, 0.6) == 0.0
    assert passive_length_factor(0.8, 5.0, 0.6) == 0.0


def test_length_factor_is_eq_2_and_one_at_strain_e_o():
    assert passive_length_factor(1.3, 5.0, 0.6) == pytest.approx(
        (math.exp(5 * 0.3 / 0.6) - 1) / (math.exp(5) - 1))
    assert passive_length_factor(1.6, 5.0, 0.6) == pytest.approx(1.0)


def test_flexion_stretches_the_extensor_and_the_torques_extend():
    m = HillPassiveMuscle("le", **YOUNG)
    y = _out(m, np.radians([37.5, 45.0, 30.0]))
    stretch = 0.0086 * math.radians(37.5) + 0.005 * math.radians(45) + 0.003 * math.radians(30)
    assert y[0] == pytest.approx(16.05 * passive_length_factor(1 + stretch / 0.07, 5.0, 0.6))
    assert y[0] > 0
    np.testing.assert_allclose(y[1:], -np.array([0.0086, 0.005, 0.003]) * y[0])


def test_old_parameters_give_a_stiffer_muscle_than_young_at_the_same_stretch():
    old = HillPassiveMuscle("le", **{**YOUNG, "k_pe": 4.0, "e_o": 0.5})
    q = np.radians([37.5, 45.0, 30.0])
    assert _out(old, q)[0] > _out(HillPassiveMuscle("le", **YOUNG), q)[0]


def test_the_literal_eq3_reading_cannot_give_the_papers_0_1082_n():
    literal = paper_literal_force_n(16.05, 0.3535, 0.07, 5.0, 0.6)
    assert literal > 1e9  # l_N = L_f / L_o ~ 5: astronomically large, not 0.1082 N
