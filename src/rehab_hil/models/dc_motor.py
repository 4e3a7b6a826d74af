"""Armature circuit of a brushed DC motor (seed 002 eq 8-9).

The mechanical side of eq 8 (J_m, B_v) is composed from ``RotaryInertia`` and
``ViscousFriction`` reflected through the gear; this part is the electrical side only:
L di/dt = V - R i - k_v omega, torque = k_t i. Constants are taken at the axis the part
is connected to (for the Finger Extensor: the gearbox output, where seed 002 measured them).
"""

from __future__ import annotations

from rehab_hil.models.system import Part, njit

__all__ = ["DCMotorArmature"]


class DCMotorArmature(Part):
    inputs = ("voltage_v", "velocity_rad_s")
    states = ("current_a",)
    outputs = ("torque_nm", "current_a")
    params = ("kt_nm_per_a", "kv_v_s_per_rad", "resistance_ohm", "inductance_h")
    feedthrough = False

    @staticmethod
    @njit
    def output(t, x, xd, u, p, y):
        y[0] = p[0] * x[0]
        y[1] = x[0]

    @staticmethod
    @njit
    def derivatives(t, x, xd, u, p, dx):
        dx[0] = (u[0] - p[2] * x[0] - p[1] * u[1]) / p[3]
