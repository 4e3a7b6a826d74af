"""Discrete PID position controller with a filtered derivative and anti-windup.

One implementation serves the offline simulation (as a diagram part, compiled with numba) and
the real-time loop (``PID`` below): the arithmetic lives in ``pid_step`` only.

Form: u = kp e + ki I + kd D, with D the derivative of the *measurement* (no kick on setpoint
steps) through a first-order filter of time constant tf, the output clamped to [u_min, u_max],
and conditional integration: the integrator freezes while the output is saturated and the
error would push it further into saturation.
"""

from __future__ import annotations

import numpy as np

from rehab_hil.models.system import Part, njit

__all__ = ["PARAMS", "PID", "STATE", "PIDController", "pid_step"]

PARAMS = ("kp", "ki", "kd", "derivative_filter_s", "output_min", "output_max", "dt_s")
STATE = ("integral", "derivative", "previous_measurement", "initialised")


@njit
def pid_terms(xd, p, reference, measurement):
    """Command, next integral and filtered derivative for this sample (no state written)."""
    kp, ki, kd, tf, umin, umax, dt = p[0], p[1], p[2], p[3], p[4], p[5], p[6]
    e = reference - measurement
    if xd[3] > 0.0:
        alpha = dt / (tf + dt)
        d = xd[1] + alpha * (-(measurement - xd[2]) / dt - xd[1])
    else:
        d = 0.0
    u_unsat = kp * e + ki * xd[0] + kd * d
    u = min(max(u_unsat, umin), umax)
    integral = xd[0]
    if not ((u_unsat > umax and e > 0.0) or (u_unsat < umin and e < 0.0)):
        integral = xd[0] + e * dt
    return u, integral, d


@njit
def pid_step(xd, p, reference, measurement, xd_next):
    """Return the command for this sample and write the controller's next state."""
    u, integral, d = pid_terms(xd, p, reference, measurement)
    xd_next[0] = integral
    xd_next[1] = d
    xd_next[2] = measurement
    xd_next[3] = 1.0
    return u


class PIDController(Part):
    """The PID as a sampled diagram part: inputs reference and measurement, output command."""

    inputs = ("reference", "measurement")
    discrete_states = STATE
    outputs = ("command",)
    params = PARAMS
    feedthrough = True

    @staticmethod
    @njit
    def output(t, x, xd, u, p, y):
        y[0] = pid_terms(xd, p, u[0], u[1])[0]

    @staticmethod
    @njit
    def update(t, x, xd, u, p, xd_next):
        pid_step(xd, p, u[0], u[1], xd_next)


class PID:
    """The same controller for the host loop: ``command = pid(reference, measurement)``."""

    def __init__(self, kp: float, ki: float, kd: float, derivative_filter_s: float,
                 output_min: float, output_max: float, dt_s: float) -> None:
        self.p = np.array([kp, ki, kd, derivative_filter_s, output_min, output_max, dt_s], float)
        self.reset()

    def reset(self) -> None:
        self.xd = np.zeros(len(STATE))
        self._next = np.zeros(len(STATE))

    def __call__(self, reference: float, measurement: float) -> float:
        u = pid_step(self.xd, self.p, float(reference), float(measurement), self._next)
        self.xd, self._next = self._next, self.xd
        return float(u)
