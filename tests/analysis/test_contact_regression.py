"""Eq 30 regression: recovers k and c from synthetic contact data and reports collinearity."""

from __future__ import annotations

import numpy as np
import pytest

from rehab_hil.analysis.contact_regression import fit_contact


def test_regression_recovers_k_and_c_within_three_standard_errors_and_five_percent():
    rng = np.random.default_rng(42)
    n = 200
    x = rng.uniform(0.8, 1.45, n)  # mm, the range of Table 4
    v = rng.uniform(0.1, 2.3, n)  # mm/s
    k, c = 0.98, 0.05
    f = k * x + c * v + rng.normal(0.0, 0.01, n)
    fit = fit_contact(f, x, v)
    assert abs(fit.k_n_per_mm - k) < 3 * fit.se[0] and abs(fit.k_n_per_mm - k) < 0.05 * k
    assert abs(fit.c_n_s_per_mm - c) < 3 * fit.se[1] and abs(fit.c_n_s_per_mm - c) < 0.1 * c
    assert fit.p[0] < 1e-6 and fit.p[1] < 1e-6
    assert fit.vif_centered < 1.2  # independent regressors


def test_collinear_regressors_show_a_large_vif():
    rng = np.random.default_rng(1)
    x = rng.uniform(0.8, 1.45, 100)
    v = 2.0 * x + rng.normal(0.0, 0.01, 100)
    fit = fit_contact(x + v, x, v)
    assert fit.vif_centered > 10.0


def test_too_few_samples_are_refused():
    with pytest.raises(ValueError, match="at least 4"):
        fit_contact(np.ones(3), np.ones(3), np.ones(3))
