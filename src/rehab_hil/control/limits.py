"""The end of a controller's chain: the effort limit and the temperature ceiling of a heated actuator."""

from __future__ import annotations

from rehab_hil.models.system import Part, njit

__all__ = ["EffortLimit", "HeatingGuard", "TemperatureCeiling"]


class EffortLimit(Part):
    """Clamps the effort demand (feedforward + feedback) to what the actuator may apply:
    [effort_min x (1 - cut), effort_max x (1 - cut)], ``cut`` in 0..1 (0 when nothing cuts the
    authority, as when unconnected; 1 forces the effort to zero, either direction). Outputs the
    applied effort and the saturation (demand - applied), which the
    feedback's anti-windup reads."""

    inputs = ("demand", "cut")
    outputs = ("effort", "saturation")
    params = ("effort_min", "effort_max")

    @staticmethod
    @njit
    def output(t, x, xd, u, p, y):
        keep = 1.0 - min(max(u[1], 0.0), 1.0)
        lo, hi = p[0] * keep, p[1] * keep
        e = min(max(u[0], lo), max(hi, lo))
        y[0] = e
        y[1] = u[0] - e


class TemperatureCeiling(Part):
    """How much of a heated actuator's authority to cut: 0 below ``ceiling_c - band_c``, rising
    linearly to 1 (all of it) at ``ceiling_c``: never hotter than the bend needs plus a margin.
    Reads an observer's temperature, a state, so it adds no algebraic loop."""

    inputs = ("temperature_c",)
    outputs = ("cut",)
    params = ("ceiling_c", "band_c")

    @staticmethod
    @njit
    def output(t, x, xd, u, p, y):
        y[0] = min(max((u[0] - p[0]) / p[1] + 1.0, 0.0), 1.0)


class HeatingGuard(Part):
    """The continuous-heating limit inside the controller: counts how long the applied effort has
    been on without a break (device time, ``dt_s`` per step, as the supervisor and the firmware
    count PWM on-time) and, once the next step would reach ``limit_s``, cuts all authority for
    ``rest_s``. So no controller ever commands a run longer than ``limit_s`` (the rig's
    ``max_heating_s`` less the host margin less a guard) whatever its feedforward or feedback
    demand: the supervisor's heating-time trip stays the backstop it is meant to be.
    Discrete states: on-time [s], rest left [s]; the output reads only them (no algebraic loop)."""

    inputs = ("effort", "dt_s")
    discrete_states = ("on_s", "rest_left_s")
    outputs = ("cut",)
    params = ("limit_s", "rest_s")
    feedthrough = False

    @staticmethod
    @njit
    def output(t, x, xd, u, p, y):
        y[0] = 1.0 if xd[1] > 0.0 else 0.0

    @staticmethod
    @njit
    def update(t, x, xd, u, p, xd_next):
        dt = max(u[1], 0.0)
        if xd[1] > 0.0:  # resting: the cut holds the effort at zero
            xd_next[0] = 0.0
            xd_next[1] = max(xd[1] - dt, 0.0)
            return
        on = xd[0] + dt if u[0] != 0.0 else 0.0
        if on > 0.0 and on + 2.0 * dt >= p[0]:  # the next step would reach the limit: rest from it
            xd_next[0] = 0.0
            xd_next[1] = p[1]
        else:
            xd_next[0] = on
            xd_next[1] = 0.0
