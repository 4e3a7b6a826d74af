"""Reference trajectories: steps and rehabilitation open-close cycles.

The same numba functions feed the offline diagrams (as source parts) and the real-time loop.
"""

from __future__ import annotations

import math

from rehab_hil.models.system import Part, njit

__all__ = ["OpenCloseReference", "SineReference", "StepReference", "open_close_reference", "step_reference"]


@njit
def step_reference(t, start, target, t_step):
    return target if t >= t_step else start


@njit
def open_close_reference(t, closed, opened, move_s, hold_open_s, hold_closed_s):
    """Closed -> (raised-cosine move) -> open, hold -> move back -> closed, hold; repeating.

    One cycle lasts 2 move_s + hold_open_s + hold_closed_s (seed 000: 5 cycles per minute)."""
    period = 2.0 * move_s + hold_open_s + hold_closed_s
    tc = t - period * math.floor(t / period)
    span = opened - closed
    if tc < move_s:
        return closed + span * 0.5 * (1.0 - math.cos(math.pi * tc / move_s))
    tc -= move_s
    if tc < hold_open_s:
        return opened
    tc -= hold_open_s
    if tc < move_s:
        return opened - span * 0.5 * (1.0 - math.cos(math.pi * tc / move_s))
    return closed


class StepReference(Part):
    """A step from ``start`` to ``target`` at ``t_step_s`` (any unit)."""

    outputs = ("reference",)
    params = ("start", "target", "t_step_s")
    feedthrough = False

    @staticmethod
    @njit
    def output(t, x, xd, u, p, y):
        y[0] = step_reference(t, p[0], p[1], p[2])


class OpenCloseReference(Part):
    """Repeating open-close cycles between ``closed`` and ``opened`` (any unit), the cycle's phase
    advanced by ``offset_s`` (a session starts in its closed hold: offset = period - hold)."""

    outputs = ("reference",)
    params = ("closed", "opened", "move_s", "hold_open_s", "hold_closed_s", "offset_s")
    feedthrough = False

    @staticmethod
    @njit
    def output(t, x, xd, u, p, y):
        y[0] = open_close_reference(t + p[5], p[0], p[1], p[2], p[3], p[4])


class SineReference(Part):
    """``offset + amplitude sin(2 pi frequency t)`` (any unit): a smooth test reference."""

    outputs = ("reference",)
    params = ("offset", "amplitude", "frequency_hz")
    feedthrough = False

    @staticmethod
    @njit
    def output(t, x, xd, u, p, y):
        y[0] = p[0] + p[1] * math.sin(2.0 * math.pi * p[2] * t)
