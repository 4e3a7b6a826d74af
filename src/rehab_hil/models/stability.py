"""How many RK4 substeps a compiled diagram needs: its fastest continuous mode at a state.

A plant config checks its own stiffest mode at load (the TCP finger's ``fastest_finger_pole``); a
part added later (a simulated patient's damping and position loop on a light robotic finger) can
make a mode far faster than the config's step allows, and RK4 then settles into a spurious state
instead of failing. ``fastest_mode`` finds the largest |eigenvalue| of the continuous states'
Jacobian by central differences of one very short RK4 step of the compiled engine (any diagram, no
hand derivation); ``substeps_for`` turns it into the substeps that keep |lambda h| below the limit.
"""

from __future__ import annotations

import math

import numpy as np

from rehab_hil.models.system import CompiledSystem

__all__ = ["RK4_LIMIT", "fastest_mode", "fastest_mode_along", "substeps_for"]

RK4_LIMIT = 2.5  # |lambda h| below RK4's real-axis stability bound 2.785, with a margin
PROBE_S = 1e-7  # the probe step [s]: lambda x PROBE_S << 1 for modes up to ~1e5 1/s
FD_STEP = 1e-6  # the state perturbation (relative, at least this absolute)


def fastest_mode(system: CompiledSystem, u: np.ndarray, x: np.ndarray | None = None,
                 xd: np.ndarray | None = None) -> float:
    """Largest |eigenvalue| [1/s] of d(dx/dt)/dx at ``x`` (default: the initial state) with inputs ``u``."""
    x0 = np.array(system.x0 if x is None else x, float)
    n = x0.size
    if n == 0:
        return 0.0
    xd0 = np.array(system.xd0 if xd is None else xd, float)
    e, P = system.engine, system.params
    sig, w, stage, xdn = system.workspace()
    e.sample(0.0, x0.copy(), xd0.copy(), u, P, sig, w, xdn)  # the outputs the derivatives read
    J = np.empty((n, n))
    for i in range(n):
        h = max(FD_STEP * abs(x0[i]), FD_STEP)
        ends = []
        for sgn in (1.0, -1.0):
            xi = x0.copy()
            xi[i] += sgn * h
            e.integrate(0.0, xi, xd0.copy(), u, P, PROBE_S, 1, sig, w, stage)
            ends.append(xi)
        J[:, i] = (ends[0] - ends[1]) / (2.0 * h)
        J[i, i] -= 1.0
    J /= PROBE_S
    return float(np.max(np.abs(np.linalg.eigvals(J))))


def fastest_mode_along(system: CompiledSystem, u: np.ndarray, duration_s: float, every_s: float = 0.01,
                       fine_step_s: float = 1e-5) -> float:
    """The largest ``fastest_mode`` along ``duration_s`` from the initial state with inputs ``u``,
    simulated with RK4 steps of ``fine_step_s`` (stable for modes up to ~2.5e5 1/s): a mode a
    switching part shows only while it is active (a patient's loop until their recruitment catches up)."""
    e, P = system.engine, system.params
    x, xd = system.x0.copy(), system.xd0.copy()
    sig, w, stage, xdn = system.workspace()
    nsub = max(1, math.ceil(system.dt / fine_step_s))
    per = max(1, round(every_s / system.dt))
    fastest = 0.0
    for k in range(max(1, round(duration_s / system.dt))):
        if k % per == 0:
            fastest = max(fastest, fastest_mode(system, u, x, xd))
        e.sample(k * system.dt, x, xd, u, P, sig, w, xdn)
        e.integrate(k * system.dt, x, xd, u, P, system.dt, nsub, sig, w, stage)
    return fastest


def substeps_for(fastest_per_s: float, step_s: float, at_least: int = 1) -> int:
    """The fewest RK4 substeps per ``step_s`` that keep ``fastest_per_s`` x h within ``RK4_LIMIT``."""
    return max(at_least, math.ceil(fastest_per_s * step_s / RK4_LIMIT))
