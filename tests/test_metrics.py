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


def second_order(t: np.ndarray, z: float = 0.5, w: float = 10.0) -> np.ndarray:
    wd = w * np.sqrt(1 - z * z)
    return 1 - np.exp(-z * w * t) * (np.cos(wd * t) + z / np.sqrt(1 - z * z) * np.sin(wd * t))


def test_recorded_tracking_counts_only_rows_with_a_reference():
    r = np.array([np.nan, 1.0, 2.0, 3.0, np.nan])  # no reference before the first command and at the stop
    a = np.array([0.0, 1.5, 2.5, 3.5, 0.0])
    assert metrics.recorded_tracking(r, a) == metrics.tracking_metrics(r[1:4], a[1:4])
    assert metrics.recorded_tracking(np.full(3, np.nan), np.zeros(3)) == {}


def test_a_recorded_step_is_judged_up_to_its_stop():
    # a 40 deg step at t = 0 answered as a second-order system (z 0.5, w 10 rad/s), then the stop's rows
    # with no reference and the angle falling away: counted, they would leave the step unsettled
    t = np.arange(0, 3.0, 1e-3)
    angle = 40.0 * second_order(t)
    ref = np.full(t.size, 40.0)
    ref[0] = np.nan  # the first row: no command yet
    stop = t > 2.5
    ref[stop], angle[stop] = np.nan, 0.0
    m = metrics.recorded_step(t, ref, angle, start=0.0)
    assert m["target"] == 40.0 and m["start"] == 0.0
    assert m["overshoot_pct"] == pytest.approx(100 * np.exp(-np.pi * 0.5 / np.sqrt(0.75)), rel=2e-3)  # 16.3 %
    assert m["overshoot"] == pytest.approx(0.4 * m["overshoot_pct"], rel=1e-9)  # deg
    assert m["rise_time_s"] == pytest.approx(0.1639, abs=2e-3)
    assert 0.6 < m["settling_time_s"] < 1.0
    assert metrics.recorded_step(t, np.full(t.size, np.nan), angle, start=0.0) == {}
