"""What the model can reach: the angle range a constant effort holds inside the rig's limits.

At each end of the actuator's authority the model runs from rest with the effort held for
``settle_s`` and the final angle is what that end can hold. A heated actuator may not use an
effort whose steady temperature exceeds the rig's temperature limit: the largest allowed effort is
found by bisection on the model's own temperature. The range of motion (inside the host margin)
bounds the rest. A reference outside the result is clipped to it with a warning; a model whose
angle does not respond to the effort (no inverse on the range) is refused.
"""

from __future__ import annotations

import numpy as np

from rehab_hil.controllers.base import ControlContext, ControllerError
from rehab_hil.controllers.feedforward import cached, fingerprint
from rehab_hil.controllers.observer import temperature_signal

__all__ = ["SETTLE_S", "reachable_range"]

SETTLE_S = 120.0  # long enough for the slowest plant (the TCP coil's 16 s thermal pole) to settle [s]
_BISECTIONS = 10


def reachable_range(ctx: ControlContext, temperature_limit_c: float | None = None,
                    settle_s: float = SETTLE_S) -> tuple[float, float]:
    """(lowest, highest) angle [deg] a constant effort holds within the rig's limits, the model's
    actuator temperature at most ``temperature_limit_c`` (default: the rig's temperature limit)."""
    limit_c = ctx.cfg.rig.limits.max_temperature_c if temperature_limit_c is None else temperature_limit_c
    key = fingerprint("reachable", ctx.cfg.model_dump(), settle_s, limit_c)
    got = cached("reachable", key, lambda: {"range": np.array(_compute(ctx, settle_s, limit_c))})["range"]
    lo, hi = float(got[0]), float(got[1])
    if not hi - lo > 0.5:
        raise ControllerError(f"{ctx.source}: the model's {ctx.angle} does not respond to {ctx.effort} "
                              f"(a held effort reaches {lo:.3g}..{hi:.3g} deg): the model has no inverse on "
                              "the range, so no model-based controller can drive it")
    return lo, hi


def _compute(ctx: ControlContext, settle_s: float, limit_c: float) -> tuple[float, float]:
    cfg, plant = ctx.cfg, ctx.plant
    system = plant.diagram(cfg).compile(*plant.step(cfg))
    n = plant.n_steps(cfg, settle_s)
    temp = temperature_signal(ctx.ports)
    outs = [ctx.angle, *([temp] if temp else [])]

    def hold(effort: float) -> tuple[float, float]:
        r = system.simulate(n, {**ctx.ports.constants, ctx.effort: effort}, outputs=outs)
        return float(r[ctx.angle][-1]), float(r[temp][-1]) if temp else -np.inf

    lo_e, hi_e = ctx.effort_bounds
    ends = []
    for end in (lo_e, hi_e):
        angle, t_c = hold(end)
        if t_c > limit_c:  # too hot to hold: the largest effort toward this end that stays cool enough
            ok, bad = 0.0, end
            for _ in range(_BISECTIONS):
                mid = 0.5 * (ok + bad)
                a_mid, t_mid = hold(mid)
                if t_mid > limit_c:
                    bad = mid
                else:
                    ok, angle = mid, a_mid
            if ok == 0.0:
                angle = hold(0.0)[0]
        ends.append(angle)
    rest = hold(0.0)[0]
    a_lo, a_hi = min(*ends, rest), max(*ends, rest)
    lim_lo, lim_hi = ctx.angle_limits_deg
    return max(a_lo, lim_lo), min(a_hi, lim_hi)

