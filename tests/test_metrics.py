"""Metrics: values on signals whose answers are known in closed form."""

from __future__ import annotations

import numpy as np
import pytest

from rehab_hil import metrics


def test_error_metrics_on_a_constant_offset():
    r = np.linspace(0, 10, 101)
    m = metrics.tracking_metrics(r, r + 0.5)
    assert m["mae"] == pytest.approx(0.5)
    assert m["rmse"] == pytest.approx(0.5)
    assert m["max_abs_error"] == pytest.approx(0.5)
    assert m["relative_error_pct"] == pytest.approx(100 * 0.5 / 5.0)


def test_step_metrics_of_a_second_order_response():
    # y = 1 - exp(-z w t) (cos(wd t) + z/sqrt(1-z^2) sin(wd t)): overshoot exp(-pi z / sqrt(1-z^2))
    z, w = 0.5, 10.0
    t = np.linspace(0, 3, 30001)
    wd = w * np.sqrt(1 - z * z)
    y = 1 - np.exp(-z * w * t) * (np.cos(wd * t) + z / np.sqrt(1 - z * z) * np.sin(wd * t))
    m = metrics.step_metrics(t, y, 0.0, 1.0)
    assert m["overshoot_pct"] == pytest.approx(100 * np.exp(-np.pi * z / np.sqrt(1 - z * z)), rel=1e-3)
    assert m["rise_time_s"] == pytest.approx(0.1639, abs=2e-3)  # 10-90 % of this system, tabulated value 1.639/w
    assert 0.6 < m["settling_time_s"] < 1.0  # 2 % band: ~4/(z w) = 0.8 s


def test_step_metrics_refuses_a_zero_step():
    with pytest.raises(ValueError, match="target != start"):
        metrics.step_metrics(np.arange(3.0), np.zeros(3), 1.0, 1.0)
