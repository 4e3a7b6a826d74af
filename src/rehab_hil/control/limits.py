"""The end of a controller's chain: the effort limit and the temperature ceiling of a heated actuator."""

from __future__ import annotations

from rehab_hil.models.system import Part, njit

__all__ = ["EffortLimit", "TemperatureCeiling"]


class EffortLimit(Part):
    """Clamps the effort demand (feedforward + feedback) to what the actuator may apply:
    [effort_min, effort_max x (1 - cut)], ``cut`` in 0..1 (0 when nothing cuts the authority, as
    when unconnected). Outputs the applied effort and the saturation (demand - applied), which the
    feedback's anti-windup reads."""

    inputs = ("demand", "cut")
    outputs = ("effort", "saturation")
    params = ("effort_min", "effort_max")

    @staticmethod
    @njit
    def output(t, x, xd, u, p, y):
        hi = p[1] * (1.0 - min(max(u[1], 0.0), 1.0))
        e = min(max(u[0], p[0]), max(hi, p[0]))
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
