"""Electro-thermal balance of a PWM-heated SMA wire (seed 000 eq 12-13, Tables 2 and 5).

    m c dT/dt = (U^2 / R) tau - h(T) A (T - T0),   h(T) = h1 + h2 T^2

with m = rho pi r^2 l, R = rho_R l / (pi r^2), A = 2 pi r l. The duty ratio tau is the
average of the PWM (its period, ~1 ms, is far below the wire's ~1 s thermal time constant).
Seed 000 gives h2 = 0.02 without units; with T in degC (its T0 = 23 degC) h(T) spans
300..~650 W/(m^2 K) over 23..140 degC, the range of forced-air convection around a thin wire,
so T in h(T) is read in degC.
"""

from __future__ import annotations

import math

from rehab_hil.models.system import Part, njit

__all__ = ["SMAThermal", "heat_flow_w", "steady_temperature_c", "wire_geometry"]


def wire_geometry(radius_m: float, length_m: float, density_kg_m3: float,
                  resistivity_ohm_m: float) -> tuple[float, float, float]:
    """(mass [kg], resistance [ohm], surface [m^2]) of a round wire (seed 000 eq 12 text)."""
    section = math.pi * radius_m**2
    return density_kg_m3 * section * length_m, resistivity_ohm_m * length_m / section, \
        2.0 * math.pi * radius_m * length_m


@njit
def heat_flow_w(temp_c, duty, voltage_v, resistance_ohm, surface_m2, h1, h2, ambient_c):
    """Net heat into the wire [W]: Joule heating minus convection (right side of eq 12)."""
    d = min(max(duty, 0.0), 1.0)
    h = h1 + h2 * temp_c * temp_c
    return voltage_v * voltage_v / resistance_ohm * d - h * surface_m2 * (temp_c - ambient_c)


def steady_temperature_c(duty: float, voltage_v: float, radius_m: float, length_m: float,
                         resistivity_ohm_m: float, h1: float, h2: float, ambient_c: float) -> float:
    """Temperature where U^2 tau / R = h(T) A (T - T0): the root of eq 12's right side (bisection;
    the balance is monotone in T above ambient)."""
    _, r_ohm, area = wire_geometry(radius_m, length_m, 1.0, resistivity_ohm_m)
    lo, hi = ambient_c, ambient_c + 2000.0
    for _ in range(200):
        mid = 0.5 * (lo + hi)
        if heat_flow_w(mid, duty, voltage_v, r_ohm, area, h1, h2, ambient_c) > 0.0:
            lo = mid
        else:
            hi = mid
    return 0.5 * (lo + hi)


class SMAThermal(Part):
    """Wire temperature [degC] from PWM duty (0..1) and supply voltage [V] (seed 000 eq 12-13)."""

    inputs = ("duty", "voltage_v")
    states = ("temperature_c",)
    outputs = ("temperature_c",)
    params = ("heat_capacity_j_per_c", "resistance_ohm", "surface_m2", "h1_w_per_m2_c",
              "h2_w_per_m2_c3", "ambient_c")
    feedthrough = False

    @staticmethod
    @njit
    def output(t, x, xd, u, p, y):
        y[0] = x[0]

    @staticmethod
    @njit
    def derivatives(t, x, xd, u, p, dx):
        dx[0] = heat_flow_w(x[0], u[0], u[1], p[1], p[2], p[3], p[4], p[5]) / p[0]

    @classmethod
    def from_wire(cls, name: str, *, radius_m: float, length_m: float, density_kg_m3: float,
                  resistivity_ohm_m: float, specific_heat_j_per_kg_c: float, h1_w_per_m2_c: float,
                  h2_w_per_m2_c3: float, ambient_c: float, **kw) -> SMAThermal:
        """Build from the wire's material and geometry (m c, R, A of eq 12); starts at ambient."""
        m, r_ohm, area = wire_geometry(radius_m, length_m, density_kg_m3, resistivity_ohm_m)
        return cls(name, x0=[ambient_c], heat_capacity_j_per_c=m * specific_heat_j_per_kg_c,
                   resistance_ohm=r_ohm, surface_m2=area, h1_w_per_m2_c=h1_w_per_m2_c,
                   h2_w_per_m2_c3=h2_w_per_m2_c3, ambient_c=ambient_c, **kw)
