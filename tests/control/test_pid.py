"""PID: textbook terms, saturation, anti-windup, and one implementation for part and host loop."""

from __future__ import annotations

import numpy as np
import pytest

from rehab_hil.control.pid import PID
from rehab_hil.control.trajectories import open_close_reference


def test_proportional_and_integral_terms():
    pid = PID(kp=2.0, ki=10.0, kd=0.0, derivative_filter_s=0.0, output_min=-100, output_max=100, dt_s=0.01)
    assert pid(1.0, 0.0) == pytest.approx(2.0)  # I starts at 0
    assert pid(1.0, 0.0) == pytest.approx(2.0 + 10.0 * 0.01)


def test_derivative_acts_on_the_measurement_not_the_setpoint():
    pid = PID(kp=0.0, ki=0.0, kd=1.0, derivative_filter_s=0.0, output_min=-100, output_max=100, dt_s=0.01)
    pid(0.0, 0.0)
    assert pid(50.0, 0.0) == pytest.approx(0.0)  # setpoint step: no kick
    assert pid(50.0, 0.1) == pytest.approx(-10.0)  # measurement rising at 10/s


def test_output_is_clamped_and_the_integrator_does_not_wind_up():
    pid = PID(kp=1.0, ki=100.0, kd=0.0, derivative_filter_s=0.0, output_min=-1, output_max=1, dt_s=0.01)
    for _ in range(1000):
        assert pid(10.0, 0.0) == pytest.approx(1.0)
    # error reverses: a wound-up integrator would hold +1 for a long time
    out = [pid(-1.0, 0.0) for _ in range(3)]
    assert out[0] == pytest.approx(-1.0)
    assert np.all(np.array(out) <= 0)


def test_open_close_reference_holds_and_moves_smoothly():
    args = (10.0, 100.0, 2.0, 1.0, 1.0)  # closed, opened, move, hold open, hold closed: period 6 s
    assert open_close_reference(0.0, *args) == pytest.approx(10.0)
    assert open_close_reference(1.0, *args) == pytest.approx(55.0)
    assert open_close_reference(2.5, *args) == pytest.approx(100.0)
    assert open_close_reference(4.0, *args) == pytest.approx(55.0)
    assert open_close_reference(5.5, *args) == pytest.approx(10.0)
    assert open_close_reference(7.0, *args) == pytest.approx(55.0)  # periodic
