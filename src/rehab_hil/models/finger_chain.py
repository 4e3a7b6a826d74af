"""Three-link planar finger: Lagrange dynamics M(q) q'' + C(q, q') q' + G(q) = tau (seed 000 eq 29).

Links are the proximal, middle and distal phalanges (seed 000 Table 3), joints MCP, PIP, DIP,
each a revolute joint about the axis normal to the sagittal plane. Joint angles are relative
(q2 is PIP flexion relative to the proximal phalanx); flexion is positive here (seed 000 counts
bending as negative in its Fig. 14 but reports positive angles in Fig. 7-9: only the sign
convention differs). Link k has its centre of mass ``com`` metres from its proximal joint (seed
000: at the link's centre) and inertia ``I`` about that centre (slender rod m L^2 / 12 by
default). Gravity is a vector (g_x, g_y) in the base frame, whose x axis points along the
extended finger, so the hand's orientation is a parameter.

``FingerChain`` is the free 3-DOF chain; ``CoupledFingerChain`` is the 1-DOF chain constrained by
the joint coupling q2 = 6/5 q1, q3 = 4/5 q1 (seed 000 eq 9), whose dynamics are the projection
s^T M s, s^T C s, s^T G onto s = (1, 6/5, 4/5); the joint torques project by s^T tau (virtual work).
The TCP finger (seed 001 eq 3-6) reuses the same chain with its own lengths and masses.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from rehab_hil.models.system import Part, njit

__all__ = [
    "CHAIN_PARAMS",
    "COUPLING",
    "CoupledFingerChain",
    "FingerChain",
    "chain_param_vector",
    "coriolis_entries",
    "coriolis_vector",
    "coupled_dynamics",
    "energy",
    "forward_dynamics",
    "gravity_entries",
    "gravity_vector",
    "inverse_dynamics",
    "mass_derivative_entries",
    "mass_entries",
    "mass_matrix",
    "mass_matrix_derivatives",
    "rod_link_params",
]

# Seed 000 eq 9: theta2 = 6/5 theta1, theta3 = 2/3 theta2 = 4/5 theta1.
COUPLING = (1.0, 1.2, 0.8)

# Parameter order shared by both parts and the free functions.
CHAIN_PARAMS = (
    "length1_m", "length2_m", "length3_m",
    "mass1_kg", "mass2_kg", "mass3_kg",
    "com1_m", "com2_m", "com3_m",
    "inertia1_kg_m2", "inertia2_kg_m2", "inertia3_kg_m2",
    "gravity_x_m_s2", "gravity_y_m_s2",
)


def rod_link_params(lengths_m: Sequence[float], masses_kg: Sequence[float],
                    gravity_m_s2: Sequence[float] = (0.0, 0.0)) -> dict[str, float]:
    """Chain parameters for uniform slender rods: centre of mass at L/2, I = m L^2 / 12.

    Seed 000 sec V: "the centroid is located at the center of each joint" (of each link)."""
    if len(lengths_m) != 3 or len(masses_kg) != 3 or len(gravity_m_s2) != 2:
        raise ValueError("need 3 lengths, 3 masses and a 2-vector of gravity")
    out: dict[str, float] = {}
    for k, (length, m) in enumerate(zip(lengths_m, masses_kg, strict=True), start=1):
        if not (length > 0 and m > 0):
            raise ValueError(f"link {k}: length and mass must be positive, got {length}, {m}")
        out[f"length{k}_m"] = float(length)
        out[f"mass{k}_kg"] = float(m)
        out[f"com{k}_m"] = 0.5 * float(length)
        out[f"inertia{k}_kg_m2"] = float(m) * float(length) ** 2 / 12.0
    out["gravity_x_m_s2"] = float(gravity_m_s2[0])
    out["gravity_y_m_s2"] = float(gravity_m_s2[1])
    return {k: out[k] for k in CHAIN_PARAMS}


def chain_param_vector(params: dict[str, float]) -> np.ndarray:
    """The 14 chain parameters as the flat vector the kernels take (order ``CHAIN_PARAMS``)."""
    return np.array([float(params[k]) for k in CHAIN_PARAMS])


@njit
def mass_entries(q2, q3, p):
    """Closed-form M(q) of the planar 3R chain (seed 000 eq 29; derivation: sum over links of
    m_k J_vk^T J_vk + I_k J_wk^T J_wk) as (M11, M12, M13, M22, M23, M33); it depends on q2, q3 only."""
    return _mass_cos(math.cos(q2), math.cos(q3), math.cos(q2 + q3), p)


@njit
def _mass_cos(c2, c3, c23, p):
    """``mass_entries`` from cos q2, cos q3, cos(q2 + q3)."""
    L1, L2 = p[0], p[1]
    m1, m2, m3 = p[3], p[4], p[5]
    a1, a2, a3 = p[6], p[7], p[8]
    i1, i2, i3 = p[9], p[10], p[11]
    m33 = i3 + m3 * a3 * a3
    m23 = m33 + m3 * L2 * a3 * c3
    m22 = i2 + m2 * a2 * a2 + i3 + m3 * (L2 * L2 + a3 * a3 + 2.0 * L2 * a3 * c3)
    m13 = m23 + m3 * L1 * a3 * c23
    m12 = m22 + m2 * L1 * a2 * c2 + m3 * (L1 * L2 * c2 + L1 * a3 * c23)
    m11 = (i1 + m1 * a1 * a1 + m22 + m2 * (L1 * L1 + 2.0 * L1 * a2 * c2)
           + m3 * (L1 * L1 + 2.0 * L1 * L2 * c2 + 2.0 * L1 * a3 * c23))
    return m11, m12, m13, m22, m23, m33


@njit
def _fill_symmetric(A, a11, a12, a13, a22, a23, a33):
    """Write the symmetric 3x3 matrix with these upper-triangle entries into ``A``."""
    A[0, 0] = a11
    A[0, 1] = A[1, 0] = a12
    A[0, 2] = A[2, 0] = a13
    A[1, 1] = a22
    A[1, 2] = A[2, 1] = a23
    A[2, 2] = a33


@njit
def mass_matrix(q, p, M):
    """M(q) of ``mass_entries`` written into the 3x3 array ``M``."""
    m11, m12, m13, m22, m23, m33 = mass_entries(q[1], q[2], p)
    _fill_symmetric(M, m11, m12, m13, m22, m23, m33)


@njit
def mass_derivative_entries(q2, q3, p):
    """Non-zero entries of dM/dq2 (d11, d12, d13) and dM/dq3 (e11, e12, e13, e22, e23); dM/dq1 = 0."""
    return _dmass_sin(math.sin(q2), math.sin(q3), math.sin(q2 + q3), p)


@njit
def _dmass_sin(s2, s3, s23, p):
    """``mass_derivative_entries`` from sin q2, sin q3, sin(q2 + q3)."""
    L1, L2 = p[0], p[1]
    m2, m3 = p[4], p[5]
    a2, a3 = p[7], p[8]
    d11 = -2.0 * L1 * (m2 * a2 + m3 * L2) * s2 - 2.0 * m3 * L1 * a3 * s23
    d12 = -L1 * (m2 * a2 + m3 * L2) * s2 - m3 * L1 * a3 * s23
    d13 = -m3 * L1 * a3 * s23
    e11 = -2.0 * m3 * L2 * a3 * s3 - 2.0 * m3 * L1 * a3 * s23
    e12 = -2.0 * m3 * L2 * a3 * s3 - m3 * L1 * a3 * s23
    e13 = -m3 * L2 * a3 * s3 - m3 * L1 * a3 * s23
    e22 = -2.0 * m3 * L2 * a3 * s3
    e23 = -m3 * L2 * a3 * s3
    return d11, d12, d13, e11, e12, e13, e22, e23


@njit
def mass_matrix_derivatives(q, p, dM2, dM3):
    """dM/dq2 and dM/dq3 of ``mass_matrix`` as 3x3 arrays (dM/dq1 = 0), for the Christoffel symbols."""
    d11, d12, d13, e11, e12, e13, e22, e23 = mass_derivative_entries(q[1], q[2], p)
    _fill_symmetric(dM2, d11, d12, d13, 0.0, 0.0, 0.0)
    _fill_symmetric(dM3, e11, e12, e13, e22, e23, 0.0)


@njit
def coriolis_entries(q2, q3, v1, v2, v3, p):
    """C(q, q') q' of seed 000 eq 29 (Coriolis and centripetal torques) from the Christoffel
    symbols of M: h_i = sum_jk (dM_ij/dq_k - 1/2 dM_jk/dq_i) v_j v_k, with dM/dq1 = 0."""
    d11, d12, d13, e11, e12, e13, e22, e23 = mass_derivative_entries(q2, q3, p)
    a1 = d11 * v1 + d12 * v2 + d13 * v3  # dM/dq2 . v
    a2 = d12 * v1
    a3 = d13 * v1
    b1 = e11 * v1 + e12 * v2 + e13 * v3  # dM/dq3 . v
    b2 = e12 * v1 + e22 * v2 + e23 * v3
    b3 = e13 * v1 + e23 * v2
    va = v1 * a1 + v2 * a2 + v3 * a3
    vb = v1 * b1 + v2 * b2 + v3 * b3
    return a1 * v2 + b1 * v3, a2 * v2 + b2 * v3 - 0.5 * va, a3 * v2 + b3 * v3 - 0.5 * vb


@njit
def coriolis_vector(q, qd, p, out):
    """``coriolis_entries`` written into ``out``."""
    out[0], out[1], out[2] = coriolis_entries(q[1], q[2], qd[0], qd[1], qd[2], p)


@njit
def gravity_entries(q1, q2, q3, p):
    """G(q) = dV/dq with V = -sum m_k g . p_ck (seed 000 eq 29), gravity g = (g_x, g_y), as a tuple."""
    L1, L2 = p[0], p[1]
    m1, m2, m3 = p[3], p[4], p[5]
    a1, a2, a3 = p[6], p[7], p[8]
    gx, gy = p[12], p[13]
    f1 = q1
    f2 = f1 + q2
    f3 = f2 + q3
    # w(phi) = g . d(cos phi, sin phi)/dphi
    w1 = -gx * math.sin(f1) + gy * math.cos(f1)
    w2 = -gx * math.sin(f2) + gy * math.cos(f2)
    w3 = -gx * math.sin(f3) + gy * math.cos(f3)
    g3 = m3 * a3 * w3
    g2 = m2 * a2 * w2 + m3 * (L2 * w2) + g3
    g1 = m1 * a1 * w1 + (m2 + m3) * L1 * w1 + g2
    return -g1, -g2, -g3


@njit
def gravity_vector(q, p, out):
    """G(q) of ``gravity_entries`` written into ``out``."""
    g1, g2, g3 = gravity_entries(q[0], q[1], q[2], p)
    out[0] = g1
    out[1] = g2
    out[2] = g3


@njit
def _solve3(m11, m12, m13, m22, m23, m33, b1, b2, b3):
    """Solve the symmetric positive definite 3x3 system M x = b by Cholesky (scalars in and out)."""
    l11 = math.sqrt(m11)
    l21 = m12 / l11
    l31 = m13 / l11
    l22 = math.sqrt(m22 - l21 * l21)
    l32 = (m23 - l31 * l21) / l22
    l33 = math.sqrt(m33 - l31 * l31 - l32 * l32)
    y1 = b1 / l11
    y2 = (b2 - l21 * y1) / l22
    y3 = (b3 - l31 * y1 - l32 * y2) / l33
    x3 = y3 / l33
    x2 = (y2 - l32 * x3) / l22
    x1 = (y1 - l21 * x2 - l31 * x3) / l11
    return x1, x2, x3


@njit
def forward_dynamics(q, qd, tau, p, qdd):
    """q'' = M(q)^-1 (tau - C(q, q') q' - G(q)) (seed 000 eq 29 solved for the acceleration)."""
    m11, m12, m13, m22, m23, m33 = mass_entries(q[1], q[2], p)
    h1, h2, h3 = coriolis_entries(q[1], q[2], qd[0], qd[1], qd[2], p)
    g1, g2, g3 = gravity_entries(q[0], q[1], q[2], p)
    qdd[0], qdd[1], qdd[2] = _solve3(m11, m12, m13, m22, m23, m33,
                                     tau[0] - h1 - g1, tau[1] - h2 - g2, tau[2] - h3 - g3)


@njit
def inverse_dynamics(q, qd, qdd, p, tau):
    """tau = M(q) q'' + C(q, q') q' + G(q) (seed 000 eq 29, left-hand side)."""
    m11, m12, m13, m22, m23, m33 = mass_entries(q[1], q[2], p)
    h1, h2, h3 = coriolis_entries(q[1], q[2], qd[0], qd[1], qd[2], p)
    g1, g2, g3 = gravity_entries(q[0], q[1], q[2], p)
    tau[0] = m11 * qdd[0] + m12 * qdd[1] + m13 * qdd[2] + h1 + g1
    tau[1] = m12 * qdd[0] + m22 * qdd[1] + m23 * qdd[2] + h2 + g2
    tau[2] = m13 * qdd[0] + m23 * qdd[1] + m33 * qdd[2] + h3 + g3


@njit
def energy(q, qd, p):
    """Kinetic plus potential energy 1/2 q'^T M q' - sum m_k g . p_ck [J] (conserved when tau = 0)."""
    M = np.empty((3, 3))
    mass_matrix(q, p, M)
    ke = 0.0
    for i in range(3):
        for j in range(3):
            ke += 0.5 * qd[i] * M[i, j] * qd[j]
    L1, L2 = p[0], p[1]
    m1, m2, m3 = p[3], p[4], p[5]
    a1, a2, a3 = p[6], p[7], p[8]
    gx, gy = p[12], p[13]
    f1 = q[0]
    f2 = f1 + q[1]
    f3 = f2 + q[2]
    x1, y1 = a1 * math.cos(f1), a1 * math.sin(f1)
    x2 = L1 * math.cos(f1) + a2 * math.cos(f2)
    y2 = L1 * math.sin(f1) + a2 * math.sin(f2)
    x3 = L1 * math.cos(f1) + L2 * math.cos(f2) + a3 * math.cos(f3)
    y3 = L1 * math.sin(f1) + L2 * math.sin(f2) + a3 * math.sin(f3)
    pe = -(m1 * (gx * x1 + gy * y1) + m2 * (gx * x2 + gy * y2) + m3 * (gx * x3 + gy * y3))
    return ke + pe


@njit
def coupled_dynamics(theta, omega, p):
    """Projected 1-DOF terms for q = s theta, s = (1, 6/5, 4/5) (seed 000 eq 9 in eq 29):
    returns (s^T M s, s^T C(q, s omega) s omega, s^T G). For one coordinate the Coriolis term is
    1/2 m'(theta) omega^2 with m' = s2 s^T (dM/dq2) s + s3 s^T (dM/dq3) s."""
    s1, s2, s3 = COUPLING[0], COUPLING[1], COUPLING[2]
    q1, q2, q3 = s1 * theta, s2 * theta, s3 * theta
    c2, sn2 = math.cos(q2), math.sin(q2)
    c3, sn3 = math.cos(q3), math.sin(q3)
    c23, sn23 = c2 * c3 - sn2 * sn3, sn2 * c3 + c2 * sn3
    m11, m12, m13, m22, m23, m33 = _mass_cos(c2, c3, c23, p)
    m_eff = (s1 * s1 * m11 + s2 * s2 * m22 + s3 * s3 * m33
             + 2.0 * (s1 * s2 * m12 + s1 * s3 * m13 + s2 * s3 * m23))
    d11, d12, d13, e11, e12, e13, e22, e23 = _dmass_sin(sn2, sn3, sn23, p)
    a2 = s1 * s1 * d11 + 2.0 * (s1 * s2 * d12 + s1 * s3 * d13)
    a3 = s1 * s1 * e11 + s2 * s2 * e22 + 2.0 * (s1 * s2 * e12 + s1 * s3 * e13 + s2 * s3 * e23)
    h_eff = 0.5 * (s2 * a2 + s3 * a3) * omega * omega
    if p[12] == 0.0 and p[13] == 0.0:
        return m_eff, h_eff, 0.0
    g1, g2, g3 = gravity_entries(q1, q2, q3, p)
    return m_eff, h_eff, s1 * g1 + s2 * g2 + s3 * g3


class FingerChain(Part):
    """Free 3-DOF finger (MCP, PIP, DIP): joint torques in [N m], angles [rad] and rates out."""

    inputs = ("tau1_nm", "tau2_nm", "tau3_nm")
    states = ("q1_rad", "q2_rad", "q3_rad", "qd1_rad_s", "qd2_rad_s", "qd3_rad_s")
    outputs = ("q1_rad", "q2_rad", "q3_rad", "qd1_rad_s", "qd2_rad_s", "qd3_rad_s")
    params = CHAIN_PARAMS
    feedthrough = False

    @staticmethod
    @njit
    def output(t, x, xd, u, p, y):
        for i in range(6):
            y[i] = x[i]

    @staticmethod
    @njit
    def derivatives(t, x, xd, u, p, dx):
        m11, m12, m13, m22, m23, m33 = mass_entries(x[1], x[2], p)
        h1, h2, h3 = coriolis_entries(x[1], x[2], x[3], x[4], x[5], p)
        g1, g2, g3 = gravity_entries(x[0], x[1], x[2], p)
        a1, a2, a3 = _solve3(m11, m12, m13, m22, m23, m33, u[0] - h1 - g1, u[1] - h2 - g2, u[2] - h3 - g3)
        dx[0] = x[3]
        dx[1] = x[4]
        dx[2] = x[5]
        dx[3] = a1
        dx[4] = a2
        dx[5] = a3


class CoupledFingerChain(Part):
    """Finger with the joint coupling of seed 000 eq 9: one state theta1 (MCP); same ports as
    ``FingerChain``, so the two are interchangeable in a diagram. Joint torques act through
    the generalised force s^T tau."""

    inputs = ("tau1_nm", "tau2_nm", "tau3_nm")
    states = ("q1_rad", "qd1_rad_s")
    outputs = ("q1_rad", "q2_rad", "q3_rad", "qd1_rad_s", "qd2_rad_s", "qd3_rad_s")
    params = CHAIN_PARAMS
    feedthrough = False

    @staticmethod
    @njit
    def output(t, x, xd, u, p, y):
        y[0] = x[0]
        y[1] = COUPLING[1] * x[0]
        y[2] = COUPLING[2] * x[0]
        y[3] = x[1]
        y[4] = COUPLING[1] * x[1]
        y[5] = COUPLING[2] * x[1]

    @staticmethod
    @njit
    def derivatives(t, x, xd, u, p, dx):
        m_eff, h_eff, g_eff = coupled_dynamics(x[0], x[1], p)
        tau = COUPLING[0] * u[0] + COUPLING[1] * u[1] + COUPLING[2] * u[2]
        dx[0] = x[1]
        dx[1] = (tau - h_eff - g_eff) / m_eff
