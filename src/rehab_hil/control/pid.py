"""Discrete PID with a filtered derivative and anti-windup, stepped with the measured sample interval.

One part serves the offline simulation and the rig: in a closed-loop diagram ``dt_s`` is the
simulation step; on the rig it is the device time since the last control step, so a loop that
controls once per burst of samples (a USB bridge delivers 2-4 at a time) integrates and
differentiates over the time that really passed.

Form: u = clamp(kp e + ki I + kd D, output_min, output_max), D the derivative of the
*measurement* (no kick on reference steps) through a first-order filter of time constant tf.
Integration is conditional (it freezes while the output saturates and the error would push it
further in): on the PID's own clamp, and on the ``saturation`` input, how far the effort limit
downstream cut the demand last sample (demand - applied), so a feedforward that uses the
actuator's authority cannot wind the feedback's integrator up either.
"""

from __future__ import annotations

from rehab_hil.models.system import Part, njit

__all__ = ["PARAMS", "STATE", "PIDController", "pid_terms"]

PARAMS = ("kp", "ki", "kd", "derivative_filter_s", "output_min", "output_max")
STATE = ("integral", "derivative", "previous_measurement", "initialised")


@njit
def pid_terms(xd, p, reference, measurement, dt, saturation):
    """Command, next integral and filtered derivative for this sample (no state written)."""
    kp, ki, kd, tf, umin, umax = p[0], p[1], p[2], p[3], p[4], p[5]
    e = reference - measurement
    d = 0.0
    if xd[3] > 0.0 and dt > 0.0:
        alpha = dt / (tf + dt)
        d = xd[1] + alpha * (-(measurement - xd[2]) / dt - xd[1])
    u_unsat = kp * e + ki * xd[0] + kd * d
    u = min(max(u_unsat, umin), umax)
    integral = xd[0]
    pushing_up = (u_unsat > umax or saturation > 0.0) and e > 0.0
    pushing_down = (u_unsat < umin or saturation < 0.0) and e < 0.0
    if not (pushing_up or pushing_down):
        integral = xd[0] + e * dt
    return u, integral, d


class PIDController(Part):
    """The PID as a sampled part: reference and measurement in (any one unit), the command out in
    the actuator's unit. ``saturation`` is read by the update only (no algebraic loop)."""

    inputs = ("reference", "measurement", "dt_s", "saturation")
    discrete_states = STATE
    outputs = ("command",)
    params = PARAMS
    feedthrough = ("reference", "measurement", "dt_s")

    @staticmethod
    @njit
    def output(t, x, xd, u, p, y):
        y[0] = pid_terms(xd, p, u[0], u[1], u[2], u[3])[0]

    @staticmethod
    @njit
    def update(t, x, xd, u, p, xd_next):
        _, integral, d = pid_terms(xd, p, u[0], u[1], u[2], u[3])
        xd_next[0] = integral
        xd_next[1] = d
        xd_next[2] = u[1]
        xd_next[3] = 1.0
