"""The 3-link finger chain against Pinocchio, and its structural properties (seed 000 eq 29)."""

from __future__ import annotations

import numpy as np
import pytest

from rehab_hil.models import finger_chain as fc
from rehab_hil.models.system import Diagram

pin = pytest.importorskip("pinocchio")

# Seed 000 Table 3 (lengths, masses) and an arbitrary tilted gravity so every G term is exercised.
P = fc.chain_param_vector(fc.rod_link_params((0.048, 0.028, 0.021), (0.125, 0.060, 0.040), (3.1, -9.3)))


def _pinocchio_model(p: np.ndarray):
    model = pin.Model()
    parent = 0
    placement = pin.SE3.Identity()
    for k in range(3):
        jid = model.addJoint(parent, pin.JointModelRZ(), placement, f"j{k + 1}")
        inertia = pin.Inertia(p[3 + k], np.array([p[6 + k], 0.0, 0.0]), np.diag([1e-9, 1e-9, p[9 + k]]))
        model.appendBodyToJoint(jid, inertia, pin.SE3.Identity())
        parent = jid
        placement = pin.SE3(np.eye(3), np.array([p[k], 0.0, 0.0]))
    model.gravity.linear = np.array([p[12], p[13], 0.0])
    return model


def _rel(a: np.ndarray, b: np.ndarray) -> float:
    return float(np.max(np.abs(a - b)) / max(np.max(np.abs(b)), 1e-300))


@pytest.fixture(scope="module")
def pin_pair():
    model = _pinocchio_model(P)
    return model, model.createData()


def test_mass_coriolis_gravity_match_pinocchio_at_random_states(pin_pair):
    model, data = pin_pair
    rng = np.random.default_rng(7)
    for _ in range(50):
        q = rng.uniform(-np.pi, np.pi, 3)
        qd = rng.uniform(-20.0, 20.0, 3)
        M = np.empty((3, 3))
        h = np.empty(3)
        g = np.empty(3)
        fc.mass_matrix(q, P, M)
        fc.coriolis_vector(q, qd, P, h)
        fc.gravity_vector(q, P, g)
        Mp = pin.crba(model, data, q)
        Mp = np.triu(Mp) + np.triu(Mp, 1).T
        gp = pin.computeGeneralizedGravity(model, data, q)
        hp = pin.nonLinearEffects(model, data, q, qd) - gp
        assert _rel(M, Mp) < 1e-9
        assert _rel(g, gp) < 1e-9
        assert _rel(h, hp) < 1e-9


def test_forward_dynamics_matches_pinocchio_aba(pin_pair):
    model, data = pin_pair
    rng = np.random.default_rng(11)
    for _ in range(20):
        q, qd, tau = rng.uniform(-2, 2, 3), rng.uniform(-5, 5, 3), rng.uniform(-0.1, 0.1, 3)
        qdd = np.empty(3)
        fc.forward_dynamics(q, qd, tau, P, qdd)
        assert _rel(qdd, pin.aba(model, data, q, qd, tau)) < 1e-9


def test_mass_matrix_is_symmetric_positive_definite():
    rng = np.random.default_rng(3)
    for _ in range(100):
        M = np.empty((3, 3))
        fc.mass_matrix(rng.uniform(-np.pi, np.pi, 3), P, M)
        assert np.array_equal(M, M.T)
        assert np.linalg.eigvalsh(M).min() > 0.0


def test_inverse_of_forward_dynamics_returns_the_torque():
    rng = np.random.default_rng(5)
    for _ in range(50):
        q, qd, tau = rng.uniform(-2, 2, 3), rng.uniform(-5, 5, 3), rng.uniform(-0.2, 0.2, 3)
        qdd = np.empty(3)
        back = np.empty(3)
        fc.forward_dynamics(q, qd, tau, P, qdd)
        fc.inverse_dynamics(q, qd, qdd, P, back)
        np.testing.assert_allclose(back, tau, rtol=1e-10, atol=1e-13)


def test_coupled_chain_is_the_free_chain_restricted_to_the_coupling():
    """s^T (M s theta'' + C + G) equals the projected 1-DOF terms (seed 000 eq 9)."""
    s = np.array(fc.COUPLING)
    theta, omega = 0.4, 1.7
    m_eff, h_eff, g_eff = fc.coupled_dynamics(theta, omega, P)
    M, h, g = np.empty((3, 3)), np.empty(3), np.empty(3)
    fc.mass_matrix(s * theta, P, M)
    fc.coriolis_vector(s * theta, s * omega, P, h)
    fc.gravity_vector(s * theta, P, g)
    assert m_eff == pytest.approx(s @ M @ s, rel=1e-12)
    assert h_eff == pytest.approx(s @ h, rel=1e-12)
    assert g_eff == pytest.approx(s @ g, rel=1e-12)


@pytest.mark.slow
def test_energy_is_conserved_without_damping_or_input():
    """Free swing under gravity, RK4 at 0.1 ms: energy drifts < 1e-6 of the peak kinetic energy."""
    params = fc.rod_link_params((0.048, 0.028, 0.021), (0.125, 0.060, 0.040), (0.0, -9.81))
    x0 = [0.3, 0.5, 0.2, 1.0, -2.0, 3.0]
    chain = fc.FingerChain("finger", x0=x0, **params)
    sys = Diagram([chain], inputs=("tau1_nm", "tau2_nm", "tau3_nm")).compile(1e-4, 1)
    res = sys.simulate(20000, outputs=["q1_rad", "q2_rad", "q3_rad", "qd1_rad_s", "qd2_rad_s", "qd3_rad_s"])
    p = fc.chain_param_vector(params)
    q = np.column_stack([res["q1_rad"], res["q2_rad"], res["q3_rad"]])
    qd = np.column_stack([res["qd1_rad_s"], res["qd2_rad_s"], res["qd3_rad_s"]])
    e = np.array([fc.energy(q[k], qd[k], p) for k in range(len(q))])
    ke = []
    for k in range(0, len(q), 50):
        M = np.empty((3, 3))
        fc.mass_matrix(q[k], p, M)
        ke.append(0.5 * qd[k] @ M @ qd[k])
    assert np.ptp(q[:, 0]) > 0.5  # it really moved
    assert np.max(np.abs(e - e[0])) < 1e-6 * max(ke)
