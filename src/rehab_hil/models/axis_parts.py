"""Parts of a generic one-axis drive (``plants/motor_axis.py``): a saturating drive input and a
constant load.

On a linear axis the torque-named signals of ``models.mechanics`` carry forces [N] and the angle
signals positions [m]: the equations are the same (Janot, Gautier and Brunot 2019, EMPS eq 1).
"""

from __future__ import annotations

from rehab_hil.models.system import Part, njit

__all__ = ["ConstantLoad", "Saturation"]


class Saturation(Part):
    """y = clip(u, -limit, limit): the drive's input range (EMPS: +-10 V, ``viradm``)."""

    inputs = ("u",)
    outputs = ("y",)
    params = ("limit",)

    @staticmethod
    @njit
    def output(t, x, xd, u, p, y):
        y[0] = min(max(u[0], -p[0]), p[0])


class ConstantLoad(Part):
    """A constant force (or torque) against the axis: -level (the ``offset`` of EMPS eq 1,
    tau = M q'' + Fv q' + Fc sgn(q') + offset, moved to the right-hand side)."""

    inputs = ()
    outputs = ("torque_nm",)
    params = ("level_nm",)
    feedthrough = False

    @staticmethod
    @njit
    def output(t, x, xd, u, p, y):
        y[0] = -p[0]
