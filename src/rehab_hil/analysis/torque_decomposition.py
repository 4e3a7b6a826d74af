"""Inverse-dynamics torque decomposition of seed 000 eq 29 and the Fig. 15-16 comparison.

From joint-angle trajectories, eq 29 solved for the active wire's torque:

    T_SMA1 = M(q) q'' + C(q, q') q' + G(q) - T_c + T_SMA2 + T_muscle      (with contact)
    T_SMA1 = M(q) q'' + C(q, q') q' + G(q)       + T_SMA2 + T_muscle      (without contact)

with T_SMA2 = r_i F_SMA2 (eq 5, 10), T_muscle = m_i F_LE (eq 1-3) and T_c = J_tip^T n F_c
(eq 8, 18). Velocities and accelerations come from a Savitzky-Golay derivative of the angles,
as one differentiates camera-tracked angles (seed 000 Fig. 11).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.signal import savgol_filter

from rehab_hil.models.contact import fingertip_lever
from rehab_hil.models.finger_chain import inverse_dynamics

__all__ = ["Decomposition", "compare", "decompose"]


@dataclass
class Decomposition:
    """Per-joint torques [N m], rows = samples, columns = MCP, PIP, DIP."""

    t: np.ndarray
    dynamics: np.ndarray
    contact: np.ndarray
    passive: np.ndarray
    muscle: np.ndarray

    @property
    def sma_with_contact(self) -> np.ndarray:
        return self.dynamics - self.contact + self.passive + self.muscle

    @property
    def sma_without_contact(self) -> np.ndarray:
        return self.dynamics + self.passive + self.muscle


def decompose(t: np.ndarray, q: np.ndarray, contact_force_n: np.ndarray, passive_tension_n: np.ndarray,
              muscle_force_n: np.ndarray, chain: np.ndarray, tendon_radii_m: np.ndarray,
              muscle_arms_m: np.ndarray, window_s: float = 0.05) -> Decomposition:
    """Eq 29 terms along a trajectory ``q`` (n x 3, rad) sampled at ``t`` (uniform)."""
    t = np.asarray(t, float)
    q = np.asarray(q, float)
    dt = float(t[1] - t[0])
    win = max(5, round(window_s / dt) | 1)
    qd = savgol_filter(q, win, 3, deriv=1, delta=dt, axis=0)
    qdd = savgol_filter(q, win, 3, deriv=2, delta=dt, axis=0)
    n = len(t)
    dyn = np.empty((n, 3))
    lev = np.empty((n, 3))
    tmp = np.empty(3)
    L1, L2, L3 = chain[0], chain[1], chain[2]
    for k in range(n):
        inverse_dynamics(q[k], qd[k], qdd[k], chain, tmp)
        dyn[k] = tmp
        fingertip_lever(q[k, 0], q[k, 1], q[k, 2], L1, L2, L3, tmp)
        lev[k] = tmp
    return Decomposition(
        t=t, dynamics=dyn, contact=lev * np.asarray(contact_force_n, float)[:, None],
        passive=np.outer(passive_tension_n, tendon_radii_m), muscle=np.outer(muscle_force_n, muscle_arms_m),
    )


def compare(actual_nm: np.ndarray, simulated_nm: np.ndarray) -> dict[str, float]:
    """Fig. 16 figures: error range (actual - simulated) in N mm, mean |error| and the accuracy
    1 - mean|error| / mean|simulated| in %."""
    err = (np.asarray(actual_nm) - np.asarray(simulated_nm)) * 1e3
    scale = float(np.mean(np.abs(simulated_nm))) * 1e3
    return {"error_min_nmm": float(err.min()), "error_max_nmm": float(err.max()),
            "mean_abs_error_nmm": float(np.mean(np.abs(err))),
            "accuracy_pct": 100.0 * (1.0 - float(np.mean(np.abs(err))) / scale) if scale > 0 else float("nan")}
