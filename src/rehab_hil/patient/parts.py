"""The patient as parts: each trait one small ``Part`` with declared inputs, states, outputs and
parameters, attached to a plant's axis the way an effect is (``patient/attach.py``).

Angles are the plant axis's own (rad). ``flexion_sign`` turns them into the finger's flexion (+1 on
an MCP axis, -1 on the Finger Extensor's iris, whose opening extends the finger); torques leave the
parts on the axis (N m, positive raises the axis angle).
"""

from __future__ import annotations

import math

from rehab_hil.control.trajectories import open_close_reference
from rehab_hil.models.system import Part, njit

__all__ = ["REFLEX_SLOTS", "PassiveFinger", "SlackingEffort", "StretchReflex", "TaskCue", "ThreeCompartmentFatigue",
           "VoluntaryDemand"]

REFLEX_SLOTS = 100  # FIFO of the stretch reflex: the longest delay is REFLEX_SLOTS - 1 plant steps (99 ms at 1 kHz)


class TaskCue(Part):
    """The target the patient is shown: the session's open-close cycle (as the host's reference,
    from the same ``[rig.session]``) on session time, seen ``reaction_s`` late [rad of the axis]."""

    inputs = ("session_time_s",)
    outputs = ("cue_rad",)
    params = ("closed_rad", "open_rad", "move_s", "hold_open_s", "hold_closed_s", "offset_s", "reaction_s")

    @staticmethod
    @njit
    def output(t, x, xd, u, p, y):
        y[0] = open_close_reference(u[0] + p[5] - p[6], p[0], p[1], p[2], p[3], p[4])


class SlackingEffort(Part):
    """The patient's effort (0..1): it decays with ``slack_time_s`` and grows with the error the patient
    sees (cue - angle), so it falls while a robot keeps the error small (Emken et al. 2007: motor
    adaptation as a greedy optimisation of error and effort). ``slack_time_s`` 0: no slacking (1)."""

    inputs = ("cue_rad", "angle_rad")
    states = ("effort",)
    outputs = ("effort",)
    params = ("slack_time_s", "error_gain_per_rad_s", "effort_min")
    feedthrough = False

    @staticmethod
    @njit
    def output(t, x, xd, u, p, y):
        y[0] = min(max(x[0], p[2]), 1.0) if p[0] > 0.0 else 1.0

    @staticmethod
    @njit
    def derivatives(t, x, xd, u, p, dx):
        if p[0] <= 0.0:
            dx[0] = 0.0
            return
        d = -x[0] / p[0] + p[1] * abs(u[0] - u[1])
        if (x[0] >= 1.0 and d > 0.0) or (x[0] <= p[2] and d < 0.0):
            d = 0.0
        dx[0] = d


class VoluntaryDemand(Part):
    """The torque the patient tries to make toward the cue: a position loop of the patient's own
    (stiffness ``kp``, damping ``kd``, and ``ki`` on the error's integral, which a person uses to
    close a steady shortfall, held within ``integral_limit_rad_s``) scaled by the effort [N m on the
    axis, before capacity]."""

    inputs = ("cue_rad", "angle_rad", "velocity_rad_s", "effort")
    states = ("error_integral",)
    outputs = ("demand_nm",)
    params = ("kp_nm_per_rad", "kd_nm_s_per_rad", "ki_nm_per_rad_s", "integral_limit_rad_s")

    @staticmethod
    @njit
    def output(t, x, xd, u, p, y):
        y[0] = u[3] * (p[0] * (u[0] - u[1]) - p[1] * u[2] + p[2] * x[0])

    @staticmethod
    @njit
    def derivatives(t, x, xd, u, p, dx):
        e = u[0] - u[1]
        dx[0] = 0.0 if (x[0] >= p[3] and e > 0.0) or (x[0] <= -p[3] and e < 0.0) else e


@njit
def _compartments(x, tl, p):
    """Xia & Frey Law 2008: the flow C from resting to active, and R with its rest multiplier."""
    ma, mf = x[0], x[1]
    mr = 1.0 - ma - mf
    if ma < tl:
        c = p[3] * (tl - ma) if mr > tl - ma else p[3] * mr
    else:
        c = p[4] * (tl - ma)
    r = p[1] * p[2] if c <= 0.0 else p[1]
    return c, r


class ThreeCompartmentFatigue(Part):
    """Three-compartment fatigue (Xia & Frey Law 2008): active M_A, fatigued M_F, resting 1 - M_A - M_F
    of the motor units; the target load is the demand over the capacity of its direction. The torque
    out is the demand, clamped to the capacity, no larger than the active share allows; the capacity
    left (1 - M_F) is an output. ``F``, ``R`` per s; ``r`` multiplies R while relaxing (Looft et al. 2018)."""

    inputs = ("demand_nm",)
    states = ("m_active", "m_fatigued")
    outputs = ("torque_nm", "capacity_fraction", "target_load")
    params = ("fatigue_per_s", "recovery_per_s", "rest_recovery_factor", "develop_per_s", "relax_per_s",
              "capacity_pos_nm", "capacity_neg_nm")

    @staticmethod
    @njit
    def output(t, x, xd, u, p, y):
        cap = p[5] if u[0] >= 0.0 else p[6]
        tl = min(abs(u[0]) / cap, 1.0) if cap > 0.0 else 0.0
        share = min(tl, max(x[0], 0.0))
        y[0] = math.copysign(share * cap, u[0])
        y[1] = 1.0 - x[1]
        y[2] = tl

    @staticmethod
    @njit
    def derivatives(t, x, xd, u, p, dx):
        cap = p[5] if u[0] >= 0.0 else p[6]
        tl = min(abs(u[0]) / cap, 1.0) if cap > 0.0 else 0.0
        c, r = _compartments(x, tl, p)
        dx[0] = c - p[0] * x[0]
        dx[1] = p[0] * x[0] - r * x[1]


class PassiveFinger(Part):
    """The finger's passive torque-angle curve, double-exponential (Kuo & Deshpande 2012): stiff near
    full extension and full flexion, zero at ``rest_flexion_rad``, plus damping. Flexion is
    ``flexion_sign`` x axis angle + ``offset_rad``."""

    inputs = ("angle_rad", "velocity_rad_s")
    outputs = ("torque_nm",)
    params = ("flexion_sign", "offset_rad", "rest_flexion_rad", "extension_scale_nm", "extension_shape_per_rad",
              "flexion_scale_nm", "flexion_shape_per_rad", "damping_nm_s_per_rad")

    @staticmethod
    @njit
    def output(t, x, xd, u, p, y):
        d = p[0] * u[0] + p[1] - p[2]
        flex = p[3] * (math.exp(-p[4] * d) - 1.0) - p[5] * (math.exp(p[6] * d) - 1.0) - p[7] * p[0] * u[1]
        y[0] = p[0] * flex


class StretchReflex(Part):
    """Spasticity: a velocity-dependent stretch reflex of the finger flexors (Lance 1980; velocity
    feedback with a threshold, van der Krogt et al. 2016): above ``threshold_rad_s`` of extension
    speed, seen ``delay_s`` late, a flexing torque of ``gain`` x (speed - threshold)."""

    inputs = ("velocity_rad_s",)
    discrete_states = tuple(f"velocity_past_{i}" for i in range(REFLEX_SLOTS))
    outputs = ("torque_nm",)
    params = ("flexion_sign", "threshold_rad_s", "gain_nm_s_per_rad", "delay_s", "step_s")
    feedthrough = False

    @staticmethod
    @njit
    def output(t, x, xd, u, p, y):
        k = min(max(int(p[3] / p[4] + 0.5), 1), REFLEX_SLOTS) - 1
        stretch = -p[0] * xd[k]  # extension speed of the finger [rad/s]
        y[0] = p[0] * p[2] * max(stretch - p[1], 0.0)

    @staticmethod
    @njit
    def update(t, x, xd, u, p, xd_next):
        for i in range(REFLEX_SLOTS - 1, 0, -1):
            xd_next[i] = xd[i - 1]
        xd_next[0] = u[0]
