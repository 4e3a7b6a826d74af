"""Human-machine contact (seed 000 eq 18-28) against the homogeneous transforms it comes from."""

from __future__ import annotations

import numpy as np
import pytest

from rehab_hil.models.contact import PAD_PARAMS, ContactForce, contact_displacement_m, fingertip_lever

L = (0.048, 0.028, 0.021)


def _rot(theta: float) -> np.ndarray:
    c, s = np.cos(theta), np.sin(theta)
    return np.array([[c, -s, 0, 0], [s, c, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1.0]])


@pytest.mark.parametrize(("theta_e", "theta_s", "c_e", "c_s"), [(0.9, 0.7, 0.097, 0.097), (0.2, 0.5, 0.1, 0.09)])
def test_displacement_equals_eq_20_to_27_with_transform_matrices(theta_e, theta_s, c_e, c_s):
    q_ce_s = np.linalg.inv(_rot(theta_s)) @ _rot(theta_e) @ np.array([c_e, 0, 0, 1.0])  # eq 20-25
    q_ces = q_ce_s[:3] - np.array([c_s, 0, 0])  # eq 19, 26
    assert contact_displacement_m(theta_e - theta_s, c_e, c_s) == pytest.approx(np.linalg.norm(q_ces), rel=1e-12)


def test_fingertip_lever_is_the_jacobian_transpose_times_the_eq8_normal():
    q = np.array([0.4, 0.6, 0.3])

    def tip(q):  # eq 6
        a = np.cumsum(q)
        return np.array([np.sum(np.array(L) * np.cos(a)), np.sum(np.array(L) * np.sin(a))])

    eps = 1e-7
    jac = np.column_stack([(tip(q + eps * np.eye(3)[i]) - tip(q - eps * np.eye(3)[i])) / (2 * eps) for i in range(3)])
    n = np.array([-np.sin(q.sum()), np.cos(q.sum())])  # eq 8 direction
    out = np.empty(3)
    fingertip_lever(q[0], q[1], q[2], *L, out)
    np.testing.assert_allclose(out, jac.T @ n, rtol=1e-7)


def test_force_passes_the_wire_torque_and_the_pad_relaxes_to_k_times_deformation():
    vals = dict(stiffness_n_per_m=981.5, damping_n_s_per_m=50.0, exo_radius_m=0.097, finger_radius_m=0.097,
                length1_m=L[0], length2_m=L[1], length3_m=L[2])
    part = ContactForce("c", **vals)
    assert part.params == PAD_PARAMS
    q = np.array([0.3, 0.36, 0.24])
    lev = np.empty(3)
    fingertip_lever(*q, *L, lev)
    lever = lev @ np.array([1.0, 1.2, 0.8])
    torque = 0.2
    force = torque / lever
    phi_eq = 2 * np.arcsin(force / 981.5 / (2 * 0.097))  # k |q_ces(phi)| = F
    y = np.zeros(5)
    part.output(0.0, np.zeros(0), np.zeros(0), np.array([torque, *q, phi_eq]), part.param_values, y)
    assert y[0] == pytest.approx(force)
    assert y[1] == pytest.approx(0.0, abs=1e-9)  # no pad motion at equilibrium
    np.testing.assert_allclose(y[2:], lev * force)
    assert np.array([1.0, 1.2, 0.8]) @ y[2:] == pytest.approx(torque)  # virtual work (eq 4)
