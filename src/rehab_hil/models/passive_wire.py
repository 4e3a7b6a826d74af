"""Passive (antagonist) SMA wire and the tendon excursion that strains both wires (seed 000 eq 5, 10-11).

    e = r1 theta1 + r2 theta2 + r3 theta3                       (eq 5, 11: path length change)
    F_SMA2 = E_M eps pi r^2,  eps = e / l                       (eq 10-11)

The cold passive wire stays martensitic and linear elastic (seed 000 sec VI.C); it only pulls,
so a negative strain (the finger extended past rest) leaves it slack at zero force.
"""

from __future__ import annotations

import math

from rehab_hil.models.system import Part, njit

__all__ = ["PassiveWire", "TendonExcursion"]


class TendonExcursion(Part):
    """Tendon path change e [m] over the three joint pulleys (eq 5), plus an exoskeleton bend
    ``offset_rad`` beyond the finger (the contact pad's deformation), spread over the joints
    as the coupling 1 : 6/5 : 4/5 of eq 9 (normalised to sum 1)."""

    inputs = ("q1_rad", "q2_rad", "q3_rad", "offset_rad")
    outputs = ("excursion_m",)
    params = ("radius1_m", "radius2_m", "radius3_m")

    @staticmethod
    @njit
    def output(t, x, xd, u, p, y):
        y[0] = (p[0] * (u[0] + u[3] / 3.0) + p[1] * (u[1] + 1.2 * u[3] / 3.0)
                + p[2] * (u[2] + 0.8 * u[3] / 3.0))


class PassiveWire(Part):
    """Tension [N] of the cold antagonist wire stretched by the excursion e [m] (eq 10-11)."""

    inputs = ("excursion_m",)
    outputs = ("tension_n",)
    params = ("martensite_modulus_pa", "radius_m", "length_m", "pretension_n")

    @staticmethod
    @njit
    def output(t, x, xd, u, p, y):
        f = p[3] + p[0] * (u[0] / p[2]) * math.pi * p[1] * p[1]
        y[0] = max(f, 0.0)
