"""Tanaka wire (seed 000 eq 14-17): branches, stress shift, bounds and thermal hysteresis."""

from __future__ import annotations

import numpy as np
import pytest

from rehab_hil.models.sma_tanaka import TANAKA_PARAMS, branch_fraction, transform, wire_stress_pa

VALUES = dict(
    martensite_modulus_pa=27e9, austenite_modulus_pa=65e9, thermoelastic_pa_per_c=0.55e6,
    stress_influence_pa_per_c=13.6e6, austenite_start_c=66.0, austenite_finish_c=78.0,
    martensite_start_c=52.0, martensite_finish_c=42.0, prestrain=0.0117, max_stress_pa=600e6,
    radius_m=0.15e-3, length_m=1.8, ambient_c=23.0,
)
P = np.array([VALUES[k] for k in TANAKA_PARAMS])


def test_heating_branch_is_the_cosine_of_eq_16_between_as_and_af():
    assert branch_fraction(60.0, 0.0, 66.0, 78.0, 13.6e6) == 1.0
    assert branch_fraction(80.0, 0.0, 66.0, 78.0, 13.6e6) == 0.0
    assert branch_fraction(72.0, 0.0, 66.0, 78.0, 13.6e6) == pytest.approx(0.5)
    # eq 16-17 verbatim: a_A = pi / (A_s - A_f), b_A = -a_A / C_A
    a_a = np.pi / (66.0 - 78.0)
    b_a = -a_a / 13.6e6
    for temp, sigma in [(68.0, 0.0), (75.0, 50e6), (80.0, 100e6)]:
        expect = 0.5 * (np.cos(a_a * (temp - 66.0) + b_a * sigma) + 1.0)
        assert branch_fraction(temp, sigma, 66.0, 78.0, 13.6e6) == pytest.approx(expect, abs=1e-12)


def test_stress_shifts_the_transformation_up_by_sigma_over_ca():
    shift = 136e6 / 13.6e6  # 10 C
    assert branch_fraction(72.0 + shift, 136e6, 66.0, 78.0, 13.6e6) == pytest.approx(0.5)


def test_stress_is_zero_cold_and_bounded_above():
    cold_rest_strain = VALUES["prestrain"]  # no excursion: the wire sits at its prestrain
    assert wire_stress_pa(1.0, cold_rest_strain, 23.0, P) == 0.0
    assert wire_stress_pa(1.0, cold_rest_strain - 0.01, 23.0, P) == 0.0  # slack: no push
    assert wire_stress_pa(0.0, 0.05, 150.0, P) == VALUES["max_stress_pa"]


def test_heating_then_cooling_gives_a_different_fraction_at_the_same_temperature():
    """With the finger bent (excursion 16 mm) the wire is martensite at 68 C when heated from cold
    but stays austenite at 68 C when cooled from 150 C (A_s = 66 > M_s = 52 plus the stress shift)."""
    e = 0.016
    hot = 1.0
    for temp in np.linspace(23.0, 150.0, 200):
        hot = transform(hot, temp, e, P)
    assert hot == 0.0
    up = 1.0
    for temp in np.linspace(23.0, 68.0, 100):
        up = transform(up, temp, e, P)
    down = hot
    for temp in np.linspace(150.0, 68.0, 100):
        down = transform(down, temp, e, P)
    assert up > 0.9 and down < 0.1
    for temp in np.linspace(68.0, 23.0, 100):
        down = transform(down, temp, e, P)
    assert down == 1.0  # below M_f the wire is martensite again


def test_a_blocked_wire_saturates_at_the_stress_bound_and_shifts_its_transformation_up():
    xi = 1.0
    for temp in np.linspace(23.0, 120.0, 200):  # no excursion: nothing lets the wire shorten
        xi = transform(xi, temp, 0.0, P)
    sigma = wire_stress_pa(xi, VALUES["prestrain"], 120.0, P)
    assert sigma == VALUES["max_stress_pa"]
    assert 0.0 < xi < 0.2  # 600 MPa / 13.6 MPa/C = 44 C shift: A_f' = 122 C, not yet reached


def test_fraction_is_consistent_with_its_own_stress():
    """The solved xi lies on the heating branch evaluated at the stress it produces."""
    excursion = 0.004  # the finger has moved: partial recovery
    xi = transform(1.0, 85.0, excursion, P)
    sigma = wire_stress_pa(xi, VALUES["prestrain"] - excursion / VALUES["length_m"], 85.0, P)
    assert 0.0 < xi < 1.0
    assert xi == pytest.approx(branch_fraction(85.0, sigma, 66.0, 78.0, 13.6e6), abs=1e-8)


def _consistency(f: float, temp: float, strain: float, start: float, finish: float) -> float:
    """f - xi_branch(T, sigma(f)): zero at the fraction consistent with its own stress."""
    return f - branch_fraction(temp, wire_stress_pa(f, strain, temp, P), start, finish, 13.6e6)


def test_the_solved_fraction_is_scipys_root_of_its_own_stress_on_both_branches():
    """Over the heating and the cooling band, at rest and bent, from any previous fraction: the fraction
    ``transform`` solves is the root scipy's brentq finds for xi = xi_branch(T, sigma(xi)), to 1e-11."""
    from scipy.optimize import brentq

    rng = np.random.default_rng(7)
    checked = 0
    for _ in range(400):
        temp, excursion, xi_old = rng.uniform(40.0, 125.0), rng.uniform(0.0, 0.02), rng.uniform(0.0, 1.0)
        strain = VALUES["prestrain"] - excursion / VALUES["length_m"]
        xi = transform(xi_old, temp, excursion, P)
        if xi == xi_old or xi in (0.0, 1.0):
            continue  # inside the hysteresis band, or at a branch's end: nothing solved
        heating = xi < xi_old
        start, finish = (66.0, 78.0) if heating else (52.0, 42.0)

        root = brentq(_consistency, 0.0, 1.0, args=(temp, strain, start, finish), xtol=1e-14)
        assert xi == pytest.approx(root, abs=1e-11), (temp, excursion, xi_old)
        checked += 1
    assert checked > 100  # most draws land in a transformation band
