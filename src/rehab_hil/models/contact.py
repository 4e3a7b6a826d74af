"""Human-machine contact: a spring-damper pad between the exoskeleton and the fingertip
(seed 000 eq 4, 8, 18-28).

Geometry (eq 22-27): the exoskeleton frame is rotated by theta_e, the finger frame by theta_s,
both about the shared base; the contact points sit c_e and c_s from the base, so in the finger
frame  q_ces = [c_e cos(theta_e - theta_s) - c_s, c_e sin(theta_e - theta_s)]  (eq 27) and
|q'_ces| = c_e |theta_e' - theta_s'|  (eq 28). Force law (eq 18): |F| = k |q_ces| + c |q'_ces|;
here with signs (F = k d + c d', d = sgn(phi) |q_ces|) because a pad that is relaxing must not
push harder, which the absolute values of eq 18 would make it do.

Closure (a modelling choice seed 000 leaves open): the soft TPU exoskeleton is massless, so the
net torque the two wires put on its (eq 9-coupled) bending coordinate must pass to the finger
through the pad, F = T_wires / lever with lever = s^T J_tip^T n (virtual work, eq 4). The pad's
deformation phi = theta_e - theta_s is the state: k d(phi) + c c_e phi' = F. The force acts on
the fingertip normal to the distal phalanx (eq 8), giving joint torques J_tip^T n F (eq 4, 6).
The pad (state) and the force (feedthrough) are two parts so the wires can read the pad's
deformation without an algebraic loop. The damping c must be positive (a Kelvin-Voigt pad);
seed 000's regression value c < 0 would make the pad unstable (docs/sma_exoskeleton.md).
"""

from __future__ import annotations

import math

from rehab_hil.models.system import Part, njit

__all__ = ["PAD_PARAMS", "ContactForce", "ContactPad", "contact_displacement_m", "fingertip_lever",
           "fingertip_lever_entries"]

PAD_PARAMS = ("stiffness_n_per_m", "damping_n_s_per_m", "exo_radius_m", "finger_radius_m",
              "length1_m", "length2_m", "length3_m")


@njit
def fingertip_lever_entries(q2, q3, L1, L2, L3):
    """J_tip^T n: joint torques per newton of a fingertip force normal to the distal phalanx
    (eq 6 differentiated, eq 8 direction), as a tuple (MCP, PIP, DIP)."""
    return L1 * math.cos(q2 + q3) + L2 * math.cos(q3) + L3, L2 * math.cos(q3) + L3, L3


@njit
def fingertip_lever(q1, q2, q3, L1, L2, L3, out):
    """``fingertip_lever_entries`` written into ``out``."""
    out[0], out[1], out[2] = fingertip_lever_entries(q2, q3, L1, L2, L3)


@njit
def contact_displacement_m(phi, c_e, c_s):
    """|q_ces| of eq 27 for the relative rotation phi = theta_e - theta_s."""
    dx = c_e * math.cos(phi) - c_s
    dy = c_e * math.sin(phi)
    return math.sqrt(dx * dx + dy * dy)


@njit
def _pad(u, phi, p):
    """Contact force [N], pad rate phi' [rad/s] and the three levers for wire torque u[0]."""
    l1, l2, l3 = fingertip_lever_entries(u[2], u[3], p[4], p[5], p[6])
    lever = l1 + 1.2 * l2 + 0.8 * l3  # s^T J^T n with s of eq 9
    force = u[0] / lever
    d = contact_displacement_m(phi, p[2], p[3]) - abs(p[2] - p[3])  # deformation from the rest gap
    spring = p[0] * d if phi >= 0.0 else -p[0] * d
    rate = (force - spring) / (p[1] * p[2])
    return force, rate, l1, l2, l3


class ContactPad(Part):
    """The pad's deformation phi = theta_e - theta_s [rad] (state) and |q_ces| [m] (eq 27).

    Inputs: ``exo_torque_nm`` (the wires' torque on the exoskeleton's coupled coordinate) and
    the finger's joint angles, which set the force the pad must carry."""

    inputs = ("exo_torque_nm", "q1_rad", "q2_rad", "q3_rad")
    states = ("phi_rad",)
    outputs = ("phi_rad", "displacement_m")
    params = PAD_PARAMS
    feedthrough = False

    @staticmethod
    @njit
    def output(t, x, xd, u, p, y):
        y[0] = x[0]
        y[1] = contact_displacement_m(x[0], p[2], p[3])

    @staticmethod
    @njit
    def derivatives(t, x, xd, u, p, dx):
        dx[0] = _pad(u, x[0], p)[1]


class ContactForce(Part):
    """The force the pad passes to the fingertip [N] (positive flexes), |q'_ces| [m/s] (eq 28)
    and the finger's joint torques J_tip^T n F [N m] (eq 4, 6, 8). Same parameters as the pad."""

    inputs = ("exo_torque_nm", "q1_rad", "q2_rad", "q3_rad", "phi_rad")
    outputs = ("force_n", "velocity_m_s", "tau1_nm", "tau2_nm", "tau3_nm")
    params = PAD_PARAMS
    feedthrough = True

    @staticmethod
    @njit
    def output(t, x, xd, u, p, y):
        force, rate, l1, l2, l3 = _pad(u, u[4], p)
        y[0] = force
        y[1] = p[2] * abs(rate)
        y[2] = l1 * force
        y[3] = l2 * force
        y[4] = l3 * force
