"""Tendon torque on the three finger joints (seed 001 eq 6).

tau = F e and tau_1, tau_2, tau_3 = alpha tau, beta tau, gamma tau (MCP, PIP, DIP). The fractions
(0.25/0.22/0.20 in seed 001) were tuned there against measured angles; the moment arm is a
parameter so that the readings discussed in docs/tcp_finger.md can be compared.
"""

from __future__ import annotations

from rehab_hil.models.system import Part, njit

__all__ = ["TendonTorqueSplit"]


class TendonTorqueSplit(Part):
    """Joint torques [N m] from the tendon force [N]: alpha/beta/gamma x F x moment arm."""

    inputs = ("force_n",)
    outputs = ("tau1_nm", "tau2_nm", "tau3_nm")
    params = ("moment_arm_m", "alpha", "beta", "gamma")

    @staticmethod
    @njit
    def output(t, x, xd, u, p, y):
        tau = u[0] * p[0]
        y[0] = p[1] * tau
        y[1] = p[2] * tau
        y[2] = p[3] * tau
