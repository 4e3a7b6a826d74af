"""PID: textbook terms, saturation, anti-windup, and dt taken from the sample interval."""

from __future__ import annotations

import numpy as np
import pytest

from rehab_hil.control.pid import STATE, PIDController
from rehab_hil.control.trajectories import open_close_reference


class Stepped:
    """The part's own kernels stepped by hand: the command for a sample, then the state update."""

    def __init__(self, kp: float, ki: float, kd: float, tf: float = 0.0, lo: float = -100.0, hi: float = 100.0):
        self.p = np.array([kp, ki, kd, tf, lo, hi])
        self.xd, self.nxt, self.y = np.zeros(len(STATE)), np.zeros(len(STATE)), np.zeros(1)

    def __call__(self, reference: float, measurement: float, dt: float = 0.01, saturation: float = 0.0) -> float:
        u = np.array([reference, measurement, dt, saturation])
        PIDController.output(0.0, np.zeros(0), self.xd, u, self.p, self.y)
        PIDController.update(0.0, np.zeros(0), self.xd, u, self.p, self.nxt)
        self.xd, self.nxt = self.nxt, self.xd
        return float(self.y[0])


def test_proportional_and_integral_terms():
    pid = Stepped(kp=2.0, ki=10.0, kd=0.0)
    assert pid(1.0, 0.0) == pytest.approx(2.0)  # I starts at 0
    assert pid(1.0, 0.0) == pytest.approx(2.0 + 10.0 * 0.01)


def test_the_integral_and_the_derivative_use_the_interval_given_not_a_fixed_period():
    """Behind a USB bridge the loop controls once per burst of ~2.2 samples: over the same time the
    integral must grow as much, and a ramp must give the same derivative, as at 1 ms."""
    every_ms, per_burst = Stepped(kp=0.0, ki=10.0, kd=0.0), Stepped(kp=0.0, ki=10.0, kd=0.0)
    for _ in range(22):
        every_ms(1.0, 0.0, dt=0.001)
    for _ in range(10):
        per_burst(1.0, 0.0, dt=0.0022)
    assert every_ms(1.0, 0.0, dt=0.001) == pytest.approx(per_burst(1.0, 0.0, dt=0.0022))
    d_ms, d_burst = Stepped(kp=0.0, ki=0.0, kd=1.0), Stepped(kp=0.0, ki=0.0, kd=1.0)
    for k in range(5):  # measurement rising at 10 units/s
        out_ms = d_ms(0.0, 10.0 * 0.001 * k, dt=0.001)
        out_burst = d_burst(0.0, 10.0 * 0.0022 * k, dt=0.0022)
    assert out_ms == pytest.approx(-10.0) and out_burst == pytest.approx(-10.0)


def test_derivative_acts_on_the_measurement_not_the_setpoint():
    pid = Stepped(kp=0.0, ki=0.0, kd=1.0)
    pid(0.0, 0.0)
    assert pid(50.0, 0.0) == pytest.approx(0.0)  # setpoint step: no kick
    assert pid(50.0, 0.1) == pytest.approx(-10.0)  # measurement rising at 10/s


def test_output_is_clamped_and_the_integrator_does_not_wind_up():
    pid = Stepped(kp=1.0, ki=100.0, kd=0.0, lo=-1.0, hi=1.0)
    for _ in range(1000):
        assert pid(10.0, 0.0) == pytest.approx(1.0)
    # error reverses: a wound-up integrator would hold +1 for a long time
    out = [pid(-1.0, 0.0) for _ in range(3)]
    assert out[0] == pytest.approx(-1.0)
    assert np.all(np.array(out) <= 0)


def test_a_limit_downstream_that_cuts_the_demand_stops_the_integrator():
    """The effort limit after the feedforward sum reports how far it cut the demand; while it cuts
    and the error pushes further, the feedback's integral must not grow."""
    cut, free = Stepped(kp=0.0, ki=10.0, kd=0.0), Stepped(kp=0.0, ki=10.0, kd=0.0)
    for _ in range(100):
        cut(1.0, 0.0, saturation=0.5)
        free(1.0, 0.0)
    assert cut(1.0, 0.0, saturation=0.5) == pytest.approx(0.0)
    assert free(1.0, 0.0) == pytest.approx(10.0)
    assert cut(-1.0, 0.0, saturation=0.5) == pytest.approx(0.0)  # error reversed: it may unwind at once
    assert cut(-1.0, 0.0, saturation=0.5) < 0.0


def test_open_close_reference_holds_and_moves_smoothly():
    args = (10.0, 100.0, 2.0, 1.0, 1.0)  # closed, opened, move, hold open, hold closed: period 6 s
    assert open_close_reference(0.0, *args) == pytest.approx(10.0)
    assert open_close_reference(1.0, *args) == pytest.approx(55.0)
    assert open_close_reference(2.5, *args) == pytest.approx(100.0)
    assert open_close_reference(4.0, *args) == pytest.approx(55.0)
    assert open_close_reference(5.5, *args) == pytest.approx(10.0)
    assert open_close_reference(7.0, *args) == pytest.approx(55.0)  # periodic
