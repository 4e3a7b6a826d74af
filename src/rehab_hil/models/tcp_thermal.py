"""Lumped-capacitance thermal model of a TCP (nylon) muscle (seed 001 eq 1a-1b).

m c_p dT/dt = P - h A_c (T - T_inf): with T_a = T - T_inf this is T_a(s)/P(s) = a / (s + b),
a = 1 / (m c_p), b = h A_c / (m c_p) (eq 1b). The seed prints eq 1b as 1 / (s + hA_c/mc_p),
dropping the 1/(m c_p) gain that its own text then names ``a``; the dimensionally sound form
a / (s + b) is used here. An alternative to the identified TF1 (eq 2a) for power -> temperature.
"""

from __future__ import annotations

from rehab_hil.models.system import Part, njit

__all__ = ["LumpedThermal"]


class LumpedThermal(Part):
    """Muscle temperature [C] from electrical power [W] by eq 1a; state T_a = T - T_inf [K]."""

    inputs = ("power_w",)
    states = ("temperature_rise_k",)
    outputs = ("temperature_c", "temperature_rise_k")
    params = ("mass_kg", "specific_heat_j_per_kg_k", "convection_w_per_m2_k", "area_m2", "ambient_c")
    feedthrough = False

    @staticmethod
    @njit
    def output(t, x, xd, u, p, y):
        y[0] = p[4] + x[0]
        y[1] = x[0]

    @staticmethod
    @njit
    def derivatives(t, x, xd, u, p, dx):
        heat_capacity = p[0] * p[1]
        dx[0] = (u[0] - p[2] * p[3] * x[0]) / heat_capacity
