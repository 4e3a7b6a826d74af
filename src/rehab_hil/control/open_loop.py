"""Open-loop command sources: a duty map from the reference (seed 000 Fig. 10) and a pulse train."""

from __future__ import annotations

import math

from rehab_hil.models.system import Part, njit

__all__ = ["DutyMap", "PulseTrain"]


class DutyMap(Part):
    """Seed 000 sec B, Fig. 10: at thermal equilibrium the bending angle rises about linearly with
    the PWM ratio from ``effort_min`` (bending starts) to ``effort_max``. A reference at or below
    ``angle_min_deg`` gets zero (the wire cools and the finger returns)."""

    inputs = ("reference",)
    outputs = ("effort",)
    params = ("effort_min", "effort_max", "angle_min_deg", "angle_max_deg")

    @staticmethod
    @njit
    def output(t, x, xd, u, p, y):
        if u[0] <= p[2]:
            y[0] = 0.0
        else:
            frac = min((u[0] - p[2]) / (p[3] - p[2]), 1.0)
            y[0] = p[0] + (p[1] - p[0]) * frac


class PulseTrain(Part):
    """``effort`` for ``on_s``, then 0 for ``off_s``, repeating (seed 001's pulsed actuation). With
    ``alternate`` = 1 every other pulse is negated (a motor behind an H-bridge goes out and back)."""

    outputs = ("effort",)
    params = ("effort", "on_s", "off_s", "alternate")
    feedthrough = False

    @staticmethod
    @njit
    def output(t, x, xd, u, p, y):
        period = p[1] + p[2]
        n = math.floor(t / period)
        tc = t - n * period
        sign = -1.0 if p[3] > 0.0 and int(n) % 2 == 1 else 1.0
        y[0] = sign * p[0] if tc < p[1] else 0.0
