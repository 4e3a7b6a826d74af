"""Sensor parts: what the rig's encoder and ADC report of the true physical signals."""

from __future__ import annotations

import math

from rehab_hil.models.system import Part, njit

__all__ = ["Gain", "QuadratureEncoder"]


class QuadratureEncoder(Part):
    """Angle quantised to whole encoder counts; outputs counts and the angle in degrees.

    ``counts_per_rev`` counts edges (4 x the disc's lines for x4 decoding)."""

    inputs = ("angle_rad",)
    outputs = ("counts", "angle_deg")
    params = ("counts_per_rev",)

    @staticmethod
    @njit
    def output(t, x, xd, u, p, y):
        c = math.floor(u[0] * p[0] / (2.0 * math.pi) + 0.5)
        y[0] = c
        y[1] = c * 360.0 / p[0]


class Gain(Part):
    """y = k u: unit conversions and sign flips (e.g. rad -> deg)."""

    inputs = ("u",)
    outputs = ("y",)
    params = ("gain",)

    @staticmethod
    @njit
    def output(t, x, xd, u, p, y):
        y[0] = p[0] * u[0]
