"""Eq 29 decomposition: recovers a known active torque from sampled joint angles alone."""

from __future__ import annotations

import numpy as np

from rehab_hil.analysis.torque_decomposition import compare, decompose
from rehab_hil.models import finger_chain as fc
from rehab_hil.models.contact import fingertip_lever

CHAIN = fc.chain_param_vector(fc.rod_link_params((0.048, 0.028, 0.021), (0.125, 0.06, 0.04), (0.0, -9.81)))


def test_decomposition_recovers_the_active_torque_from_angles_alone():
    """A bend q(t) = A (1 - cos(pi t / T)) / 2 with analytic q', q''; the wire torque that
    makes it happen under passive, muscle and contact loads is recovered from q samples."""
    dt, n, period = 1e-3, 3000, 3.0
    t = np.arange(n) * dt
    amp = np.radians([37.5, 45.0, 30.0])
    w = np.pi / period
    q = np.outer(0.5 * (1 - np.cos(w * t)), amp)
    qd = np.outer(0.5 * w * np.sin(w * t), amp)
    qdd = np.outer(0.5 * w * w * np.cos(w * t), amp)
    r = np.array([0.010, 0.008, 0.006])
    arms = np.array([0.0086, 0.005, 0.003])
    f_pas = 10.0 * q[:, 0]
    f_mus = 0.3 * q[:, 0]
    f_con = 0.5 + 0.2 * np.sin(2 * np.pi * t)
    true = np.empty((n, 3))
    tau = np.empty(3)
    lev = np.empty(3)
    for k in range(n):  # eq 29: M q'' + C + G = T_SMA1 + T_c - T_SMA2 - T_muscle
        fc.inverse_dynamics(q[k], qd[k], qdd[k], CHAIN, tau)
        fingertip_lever(*q[k], *CHAIN[:3], lev)
        true[k] = tau - lev * f_con[k] + r * f_pas[k] + arms * f_mus[k]
    dec = decompose(t, q, f_con, f_pas, f_mus, CHAIN, r, arms, window_s=0.05)
    inner = slice(100, n - 100)
    err = np.max(np.abs(dec.sma_with_contact[inner] - true[inner]))
    assert err < 1e-3 * np.max(np.abs(true[inner]))
    err_without = np.max(np.abs(dec.sma_without_contact[inner] - true[inner]))
    assert err_without > 100 * err  # leaving out T_c is a real error here
    m = compare(dec.sma_with_contact[inner, 0], true[inner, 0])
    assert m["accuracy_pct"] > 99.9 and m["error_min_nmm"] <= m["error_max_nmm"]
