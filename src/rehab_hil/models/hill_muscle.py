"""Passive force of the long extensor (LE) by the Hill model, as joint torques (seed 000 eq 1-3, Table 1).

    F = F_o fl_PEE(l_N),  fl_PEE = (exp(k_pe (l_N - 1) / e_o) - 1) / (exp(k_pe) - 1) for l_N > 1, else 0

Young: k_pe = 5, e_o = 0.6; old: k_pe = 4, e_o = 0.5 (seed 000 sec II.B, its ref. [17]).
Seed 000 eq 3 sets l_N = L_f / L_o with L_f the *tendon slack length*: Table 1 gives
L_f / L_o = 4.6..5.5, for which fl_PEE ~ 1e11..1e13 and F ~ 1e12 N, so the printed 0.1082 N
cannot follow from it. The physically sound reading (Zajac, seed 000 ref. [16]) is that l_N is
the normalised *fibre* length: with the tendon inextensible (SEE disregarded, sec II.B) the fibre
takes up the whole musculotendon stretch, l_N = l_N0 + (m1 q1 + m2 q2 + m3 q3) / L_o, with m_i the
LE's extensor moment arms; flexion lengthens the LE, so it resists with torques -m_i F.
"""

from __future__ import annotations

import math

from rehab_hil.models.system import Part, njit

__all__ = ["HillPassiveMuscle", "paper_literal_force_n", "passive_length_factor"]


@njit
def passive_length_factor(l_n, k_pe, e_o):
    """fl_PEE of seed 000 eq 2."""
    if l_n <= 1.0:
        return 0.0
    return (math.exp(k_pe * (l_n - 1.0) / e_o) - 1.0) / (math.exp(k_pe) - 1.0)


def paper_literal_force_n(f_o_n: float, tendon_slack_m: float, optimal_fibre_m: float,
                          k_pe: float, e_o: float) -> float:
    """Eq 1-3 read literally (l_N = L_f / L_o): what Table 1 gives, to compare with 0.1082 N."""
    return f_o_n * passive_length_factor(tendon_slack_m / optimal_fibre_m, k_pe, e_o)


class HillPassiveMuscle(Part):
    """LE passive force [N] and its joint torques [N m] (negative: extending) from joint angles."""

    inputs = ("q1_rad", "q2_rad", "q3_rad")
    outputs = ("force_n", "tau1_nm", "tau2_nm", "tau3_nm")
    params = ("max_isometric_force_n", "optimal_fibre_length_m", "rest_length_ratio", "k_pe", "e_o",
              "moment_arm1_m", "moment_arm2_m", "moment_arm3_m")

    @staticmethod
    @njit
    def output(t, x, xd, u, p, y):
        stretch = p[5] * u[0] + p[6] * u[1] + p[7] * u[2]
        f = p[0] * passive_length_factor(p[2] + stretch / p[1], p[3], p[4])
        y[0] = f
        y[1] = -p[5] * f
        y[2] = -p[6] * f
        y[3] = -p[7] * f
