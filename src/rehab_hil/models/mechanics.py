"""Rigid-body rotation and the torques that act on one rotary axis (seed 002, eq 1-7).

Each effect is its own part so that friction, springs and loads are added by composition:
a torque part outputs onto a named torque signal, and the inertia integrates the sum.
"""

from __future__ import annotations

import math

from rehab_hil.models.system import Part, njit

__all__ = ["CoulombFriction", "HardStop", "RotaryInertia", "TorsionSpring", "ViscousFriction"]


class RotaryInertia(Part):
    """J theta'' = sum of torques (seed 002 eq 1 with M = J, D = G = 0 for the 1-DOF iris)."""

    inputs = ("torque_nm",)
    states = ("angle_rad", "velocity_rad_s")
    outputs = ("angle_rad", "velocity_rad_s")
    params = ("inertia_kg_m2",)
    feedthrough = False

    @staticmethod
    @njit
    def output(t, x, xd, u, p, y):
        y[0] = x[0]
        y[1] = x[1]

    @staticmethod
    @njit
    def derivatives(t, x, xd, u, p, dx):
        dx[0] = x[1]
        dx[1] = u[0] / p[0]


class TorsionSpring(Part):
    """Restoring torque -k (theta - theta0) (the k1 spring of seed 002 eq 2, 6)."""

    inputs = ("angle_rad",)
    outputs = ("torque_nm",)
    params = ("stiffness_nm_per_rad", "rest_angle_rad")

    @staticmethod
    @njit
    def output(t, x, xd, u, p, y):
        y[0] = -p[0] * (u[0] - p[1])


class HardStop(Part):
    """A lower mechanical end stop: below ``stop_angle_rad`` a stiff spring-damper pushes back,
    never pulls (a one-sided contact; the closed stop a motor can be homed against)."""

    inputs = ("angle_rad", "velocity_rad_s")
    outputs = ("torque_nm",)
    params = ("stiffness_nm_per_rad", "damping_nm_s_per_rad", "stop_angle_rad")

    @staticmethod
    @njit
    def output(t, x, xd, u, p, y):
        pen = p[2] - u[0]
        y[0] = max(0.0, p[0] * pen - p[1] * u[1]) if pen > 0.0 else 0.0


class ViscousFriction(Part):
    """Viscous torque -b omega (the V_c term of seed 002 eq 6-7, and B_v of eq 8)."""

    inputs = ("velocity_rad_s",)
    outputs = ("torque_nm",)
    params = ("damping_nm_s_per_rad",)

    @staticmethod
    @njit
    def output(t, x, xd, u, p, y):
        y[0] = -p[0] * u[0]


@njit
def coulomb_torque(velocity, other_torque, level, stick_velocity, stick_damping):
    """Karnopp stick-slip friction: F_c sgn(omega) when sliding (seed 002 eq 6), and inside
    the stick band the torque that cancels the others (up to F_c) plus a damping that brings
    the residual velocity to rest, so a fixed-step integrator holds the axis still."""
    if abs(velocity) > stick_velocity:
        return -level * math.copysign(1.0, velocity)
    hold = -other_torque - stick_damping * velocity
    if hold > level:
        return level
    if hold < -level:
        return -level
    return hold


class CoulombFriction(Part):
    """Coulomb friction with stiction; reads the sum of the other torques on the axis."""

    inputs = ("velocity_rad_s", "other_torque_nm")
    outputs = ("torque_nm",)
    params = ("level_nm", "stick_velocity_rad_s", "stick_damping_nm_s_per_rad")

    @staticmethod
    @njit
    def output(t, x, xd, u, p, y):
        y[0] = coulomb_torque(u[0], u[1], p[0], p[1], p[2])
