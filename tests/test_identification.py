"""Transfer-function identification: recovers a known model from noisy data, scores as MATLAB
does, compares orders with a penalty, and refuses records that cannot identify anything."""

from __future__ import annotations

import control
import numpy as np
import pytest
from scipy import signal

from rehab_hil.identification import (
    IdentificationError,
    compare_orders,
    fit_percent,
    fit_tf,
    mean_squared_error,
    recommend,
    simulate_tf,
    zoh_discretize,
)

# seed 001 eq 2a (TF1): poles -2.0506 and -0.0614, zero +3.196 (non-minimum phase)
TRUE_NUM, TRUE_DEN = [-2.072, 6.622], [1.0, 2.112, 0.1259]
DT = 0.01


def _record(seed: int = 7, noise_k: float = 1.0):
    """60 s of 34 W pulses of random widths (the power input), temperature with white noise."""
    rng = np.random.default_rng(seed)
    t = np.arange(0.0, 60.0, DT)
    u = np.zeros_like(t)
    k = 100
    while k < t.size:
        width = rng.integers(50, 400)
        u[k:k + width] = 34.0
        k += width + rng.integers(200, 800)
    y = 25.0 + simulate_tf(TRUE_NUM, TRUE_DEN, u, DT) + rng.normal(0.0, noise_k, t.size)
    return t, u, y


def test_fit_percent_is_100_for_a_perfect_model_and_0_for_the_mean():
    y = np.sin(np.linspace(0, 6, 200)) + 3.0
    assert fit_percent(y, y) == pytest.approx(100.0)
    assert fit_percent(y, np.full_like(y, y.mean())) == pytest.approx(0.0, abs=1e-12)
    yhat = y + 0.1
    expected = 100 * (1 - np.sqrt(np.sum(0.1**2 * np.ones_like(y))) / np.linalg.norm(y - y.mean()))
    assert fit_percent(y, yhat) == pytest.approx(expected)
    assert mean_squared_error(y, yhat) == pytest.approx(0.01)


def test_zoh_discretisation_matches_scipy():
    for num, den in ((TRUE_NUM, TRUE_DEN), ([0.01899, 0.002551, -0.0001572], [1, 0.3987, 1.513e-6]),
                     ([1.0], [1.0, 3.0, 3.0, 1.0])):
        numd, dend, _ = signal.cont2discrete((num, den), 0.005, method="zoh")
        a, b = zoh_discretize(num, den, 0.005)
        np.testing.assert_allclose(a, np.ravel(numd), atol=1e-12)
        np.testing.assert_allclose(b, np.ravel(dend), atol=1e-12)


def test_a_known_second_order_model_is_recovered_from_noisy_data():
    t, u, y = _record()
    res = fit_tf(t, u, y, n_poles=2, n_zeros=1)
    # noise is 1 K on a ~100 K response: the fit must reach 95 % and the poles 5 %
    assert res.fit_pct > 95.0
    true_poles = np.sort(np.real(control.tf(TRUE_NUM, TRUE_DEN).poles()))
    got = np.sort(np.real(res.poles))
    np.testing.assert_allclose(got, true_poles, rtol=0.05)
    np.testing.assert_allclose(control.dcgain(res.tf), 6.622 / 0.1259, rtol=0.05)


def test_higher_orders_are_compared_and_the_penalised_best_has_two_poles_or_more():
    t, u, y = _record(seed=3)
    results = compare_orders(t, u, y, orders=[1, 2], zeros=[0, 1])
    assert [(r.n_poles, r.n_zeros) for r in results] == [(1, 0), (1, 1), (2, 0), (2, 1)]
    by = {(r.n_poles, r.n_zeros): r for r in results}
    assert by[(2, 1)].fit_pct > by[(1, 1)].fit_pct + 5.0  # a first-order model cannot follow TF1
    best = recommend(results)
    assert best is by[(2, 1)]
    assert best.aic == min(r.aic for r in results)


def test_a_too_short_record_is_refused():
    t, u, y = _record()
    with pytest.raises(IdentificationError, match="too short"):
        fit_tf(t[:30], u[:30], y[:30], 2, 1)


def test_a_constant_input_is_refused():
    t, _, y = _record()
    with pytest.raises(IdentificationError, match="input is constant"):
        fit_tf(t, np.full_like(t, 34.0), y, 2, 1)


def test_a_constant_output_and_an_uneven_time_base_are_refused():
    t, u, y = _record()
    with pytest.raises(IdentificationError, match="output is constant"):
        fit_tf(t, u, np.full_like(t, 25.0), 1, 0)
    t2 = t.copy()
    t2[100:] += 0.5
    with pytest.raises(IdentificationError, match="uniformly sampled"):
        fit_tf(t2, u, y, 1, 0)


def test_more_zeros_than_poles_is_refused():
    t, u, y = _record()
    with pytest.raises(IdentificationError, match="zeros <= poles"):
        fit_tf(t, u, y, 1, 2)
