"""Active SMA wire: Tanaka constitutive law with cosine phase kinetics and thermal hysteresis
(seed 000 eq 14-17, Table 2).

Stress (eq 14 integrated from the cold, fully martensitic, prestrained wire at T0, with
Omega = -eps_p E, the usual choice that makes the transformation recover the prestrain):

    sigma = E(xi) (eps - eps_p xi) + Theta (T - T0),    E(xi) = E_A + xi (E_M - E_A)   (eq 15)

where eps = eps_p - e / l is the wire strain after the tendon excursion e (the wire shortens
as the finger flexes), eps_p <= eps_L the prestrain (recovery is limited by eps_L, Table 2),
and sigma is bounded to [0, sigma_max] (a wire cannot push; sigma_max is the wire's safe
stress). Martensite fraction (eq 16-17, Liang-Rogers cosine form that seed 000 calls Tanaka):

    heating  xi_A = 1/2 {cos[a_A (T - A_s) + b_A sigma] + 1},  a_A = pi / (A_f - A_s), b_A = -a_A / C_A
    cooling  xi_M = 1/2 {cos[a_M (T - M_f) + b_M sigma] + 1},  a_M = pi / (M_s - M_f), b_M = -a_M / C_A

each clamped to 1 below and 0 above its band. Seed 000 prints a_A = pi / (A_s - A_f) < 0; with
b_A = -a_A / C_A the argument is a_A (T - A_s - sigma / C_A) and cos is even, so it is the same
curve. Table 2 gives C_A = 13.6e6 "MPa/C": physically 13.6 MPa/C (= 13.6e6 Pa/C; 13.6e12 Pa/C
would make the stress shift vanish). Seed 000 gives only the
heating branch; M_s, M_f come from the Flexinol data (configs/sma_exoskeleton.toml).
Hysteresis: xi stays inside the band [xi_M, xi_A] and moves only when a branch pushes it
(heating lowers xi to xi_A, cooling raises it to xi_M): the major loop exactly, flat minor loops.
Because sigma depends on xi and xi on sigma, each sample solves xi = xi_branch(T, sigma(xi)) (the
residual is monotone: Newton's steps kept inside a shrinking bracket), so there is no algebraic lag.
"""

from __future__ import annotations

import math

from rehab_hil.models.system import Part, njit

__all__ = ["TANAKA_PARAMS", "SMATanakaWire", "branch_fraction", "transform", "wire_stress_pa"]

TANAKA_PARAMS = (
    "martensite_modulus_pa", "austenite_modulus_pa", "thermoelastic_pa_per_c",
    "stress_influence_pa_per_c", "austenite_start_c", "austenite_finish_c",
    "martensite_start_c", "martensite_finish_c", "prestrain", "max_stress_pa",
    "radius_m", "length_m", "ambient_c",
)


@njit
def branch_fraction(temp_c, stress_pa, start_c, finish_c, c_pa_per_c):
    """Martensite fraction on one cosine branch (eq 16-17) between start and finish temperatures
    (shifted up by sigma / C_A); 1 on the cold side, 0 on the hot side."""
    lo = min(start_c, finish_c)
    hi = max(start_c, finish_c)
    te = temp_c - stress_pa / c_pa_per_c
    if te <= lo:
        return 1.0
    if te >= hi:
        return 0.0
    return 0.5 * (math.cos(math.pi * (te - lo) / (hi - lo)) + 1.0)


@njit
def _unbounded_stress_pa(xi, strain, temp_c, p):
    """Tanaka stress (eq 14-15 integrated, see module doc) before its bounds."""
    e_mod = p[1] + xi * (p[0] - p[1])
    return e_mod * (strain - p[8] * xi) + p[2] * (temp_c - p[12])


@njit
def wire_stress_pa(xi, strain, temp_c, p):
    """Tanaka stress (eq 14-15 integrated, see module doc), bounded to [0, sigma_max]."""
    return min(max(_unbounded_stress_pa(xi, strain, temp_c, p), 0.0), p[9])


@njit
def _residual(xi, temp_c, strain, p, start_c, finish_c):
    """g(xi) = xi - xi_branch(T, sigma(xi)) and its slope dg/dxi (increasing in xi: the root is unique)."""
    raw = _unbounded_stress_pa(xi, strain, temp_c, p)
    sigma = min(max(raw, 0.0), p[9])
    g = xi - branch_fraction(temp_c, sigma, start_c, finish_c, p[3])
    lo = min(start_c, finish_c)
    hi = max(start_c, finish_c)
    te = temp_c - sigma / p[3]
    if not (lo < te < hi and 0.0 < raw < p[9]):  # outside the band, or the stress at a bound: xi_branch is flat
        return g, 1.0
    d_sigma = (p[0] - p[1]) * (strain - p[8] * xi) - (p[1] + xi * (p[0] - p[1])) * p[8]
    # d xi_branch / d xi = -1/2 sin(phase) d phase/d te d te/d sigma d sigma/d xi, d te/d sigma = -1/C_A
    slope = 1.0 - 0.5 * math.sin(math.pi * (te - lo) / (hi - lo)) * math.pi / (hi - lo) * d_sigma / p[3]
    return g, slope


@njit
def _solve_branch(temp_c, strain, p, start_c, finish_c, guess):
    """Root of xi - xi_branch(T, sigma(xi)): the fraction consistent with its own stress. Newton's
    steps from ``guess`` (the previous sample's fraction: two or three steps), each kept inside a
    bracket of the root that shrinks every step, a step that would leave it replaced by the bracket's
    midpoint (the residual has kinks where the stress meets its bounds): as sure as bisection, which
    took 32 cosines per solve to reach 2e-10 where this reaches 1e-13."""
    if branch_fraction(temp_c, wire_stress_pa(0.0, strain, temp_c, p), start_c, finish_c, p[3]) == 0.0:
        return 0.0
    if branch_fraction(temp_c, wire_stress_pa(1.0, strain, temp_c, p), start_c, finish_c, p[3]) == 1.0:
        return 1.0
    lo, hi = 0.0, 1.0
    xi = min(max(guess, 0.0), 1.0)
    for _ in range(64):
        g, slope = _residual(xi, temp_c, strain, p, start_c, finish_c)
        if g > 0.0:
            hi = xi
        elif g < 0.0:
            lo = xi
        else:
            return xi
        nxt = xi - g / slope if slope > 0.0 else 0.5 * (lo + hi)
        if not lo < nxt < hi:
            nxt = 0.5 * (lo + hi)
        if abs(nxt - xi) <= 1e-13 or hi - lo <= 1e-13:
            return nxt
        xi = nxt
    return 0.5 * (lo + hi)


@njit
def transform(xi_old, temp_c, excursion_m, p):
    """New martensite fraction after a sample at temperature T and tendon excursion e."""
    strain = p[8] - excursion_m / p[11]
    sigma = wire_stress_pa(xi_old, strain, temp_c, p)
    # the residual xi - xi_branch(sigma(xi)) increases with xi: its sign at xi_old says whether
    # the branch's consistent fraction lies below (heating moves xi) or above (cooling moves xi)
    if xi_old > branch_fraction(temp_c, sigma, p[4], p[5], p[3]):
        return _solve_branch(temp_c, strain, p, p[4], p[5], xi_old)
    if xi_old < branch_fraction(temp_c, sigma, p[6], p[7], p[3]):
        return _solve_branch(temp_c, strain, p, p[6], p[7], xi_old)
    return xi_old


class SMATanakaWire(Part):
    """Active wire tension [N] from temperature [degC] and tendon excursion [m]; martensite
    fraction xi is the discrete state (1 = cold martensite, 0 = austenite)."""

    inputs = ("temperature_c", "excursion_m")
    discrete_states = ("xi",)
    outputs = ("tension_n", "stress_pa", "xi")
    params = TANAKA_PARAMS
    feedthrough = True

    @staticmethod
    @njit
    def output(t, x, xd, u, p, y):
        xi = transform(xd[0], u[0], u[1], p)
        s = wire_stress_pa(xi, p[8] - u[1] / p[11], u[0], p)
        y[0] = s * math.pi * p[10] * p[10]
        y[1] = s
        y[2] = xi

    @staticmethod
    @njit
    def update(t, x, xd, u, p, xd_next):
        xd_next[0] = transform(xd[0], u[0], u[1], p)
