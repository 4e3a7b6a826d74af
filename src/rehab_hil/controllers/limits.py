"""The limits every controller carries at the end of its chain, whatever computes its demand.

    demand --> effort limit --> actuator
                 ^   ^
                 |   +-- heating guard: a rest before the run reaches max_heating_s less the margins
                 +------ temperature ceiling on the model's thermal part (heated actuators)

The supervisor and the firmware trip on continuous heating and on the estimated temperature;
before this module only they knew those limits, so a PID holding an SMA wire through a long hold
tripped the session (issue 39). Here each controller plans and commands inside them by design:
``safety_parts`` adds the heating guard (``control.limits.HeatingGuard``) and the effort limit,
and ``thermal_guard`` the observer and ceiling for a plant whose actuator heats.
"""

from __future__ import annotations

from collections.abc import Sequence

from rehab_hil.control.limits import EffortLimit, HeatingGuard, TemperatureCeiling
from rehab_hil.controllers.base import DT, ControlContext
from rehab_hil.controllers.observer import OBSERVER, temperature_signal, thermal_slice
from rehab_hil.models.lti import peak_after_cut_part
from rehab_hil.models.system import Part
from rehab_hil.plants.registry import compose

__all__ = [
    "HEATING_GUARD_S",
    "HEATING_REST_S",
    "guarded",
    "heating_limit_s",
    "mechanical_signals",
    "observer_constants",
    "safety_parts",
    "temperature_budget_c",
    "thermal_guard",
]

HEATING_GUARD_S = 0.05  # the guard rests this long before the host's heating-time trip [s]: a USB burst (4 ms) and
#                         the supervisor's count to the end of the period fit inside it
HEATING_REST_S = 0.1  # the guard's rest [s]: the supervisor and the firmware restart their count after one period
#                       off; 0.1 s is a tenth of the SMA wire's thermal time constant (a dip, not a release)


def heating_limit_s(ctx: ControlContext) -> float:
    """The longest continuous run a controller may command: ``rig.limits.max_heating_s`` less
    ``rig.host.heating_margin_s`` (the supervisor's trip) less ``HEATING_GUARD_S`` [s]."""
    return ctx.cfg.rig.host_limits().max_heating_s - HEATING_GUARD_S


def temperature_budget_c(ctx: ControlContext, budget_c: float | None = None) -> float:
    """The hottest a controller may hold its actuator: its own budget, never above the rig's
    ``rig.limits.max_temperature_c`` [C]."""
    limit = ctx.cfg.rig.limits.max_temperature_c
    return limit if budget_c is None else min(limit, budget_c)


def mechanical_signals(ctx: ControlContext) -> tuple[str, ...]:
    """The plant's joint signals (an observer must not depend on them)."""
    return tuple(s for ax in ctx.ports.axes for s in (ax.angle, ax.velocity, ax.torque))


def thermal_guard(ctx: ControlContext, ceiling_c: float, band_c: float
                  ) -> tuple[list[Part], str | None, str | None]:
    """The model's thermal part run on the applied effort and a ceiling on it: (parts, the cut
    signal, the observer's temperature signal); no parts when the plant's actuator does not heat
    (or its temperature depends on the joint: no observer from the effort alone)."""
    temp = temperature_signal(ctx.ports)
    observer = (thermal_slice(compose(ctx.plant, ctx.cfg), ctx.effort, temp, ctx.ports.constants,
                              mechanical_signals(ctx)) if temp else None)
    if observer is None or temp is None:
        return [], None, None
    peak = _peak_after_cut(observer, OBSERVER + temp)
    watched = peak.signal_names[0] if peak is not None else OBSERVER + temp
    ceiling = TemperatureCeiling("ceiling", connect={"temperature_c": watched},
                                 rename={"cut": "temperature_cut"}, ceiling_c=ceiling_c, band_c=band_c)
    return [*observer, *([peak] if peak else []), ceiling], "temperature_cut", OBSERVER + temp


def _peak_after_cut(observer: Sequence[Part], temperature: str) -> Part | None:
    """Where the observer's temperature is an LTI part's output, the most it can still rise once the
    power is cut (``models.lti.PeakAfterCut``: the TCP coil's TF_TP002 hides 2.7 C per watt in a fast
    mode that gives it back within a second of a cut; a ceiling on the temperature itself let the
    coil's estimate pass its trip). None where the temperature is its own bound (a first-order wire)."""
    source = next((p for p in observer if p.signal_names == (temperature,)), None)
    if source is None or "u" not in source.connections:
        return None
    return peak_after_cut_part(OBSERVER + "peak_after_cut", source, connect={"u": source.connections["u"]},
                               rename={"peak": temperature + "_peak_after_cut"})


def observer_constants(ctx: ControlContext, parts: Sequence[Part]) -> dict[str, float]:
    """The plant constants the parts read (the SMA observer's supply voltage)."""
    read = {s for p in parts for terms in p.connections.values() for s, _ in terms}
    return {k: v for k, v in ctx.ports.constants.items() if k in read}


def safety_parts(ctx: ControlContext, demand: str, cuts: Sequence[str] = ()) -> list[Part]:
    """The last links before the actuator: the heating guard and the effort limit, which clamps
    ``demand`` to what PWM may apply and cuts it by the guard and by ``cuts`` (a ceiling's)."""
    lo, hi = ctx.effort_bounds
    guard = HeatingGuard("heating_guard", connect={"effort": ctx.effort, "dt_s": DT}, rename={"cut": "heating_cut"},
                         limit_s=heating_limit_s(ctx), rest_s=HEATING_REST_S)
    limit = EffortLimit("limit", connect={"demand": demand, "cut": [*cuts, "heating_cut"]},
                        rename={"effort": ctx.effort, "saturation": f"{ctx.effort}_saturation"},
                        effort_min=lo, effort_max=hi)
    return [guard, limit]


def guarded(ctx: ControlContext, demand: str, budget_c: float | None = None,
            band_c: float = 5.0) -> tuple[list[Part], dict[str, float]]:
    """Every controller's end of chain: for a heated actuator the observer and a ceiling at the
    controller's temperature budget (the rig's limit by default), then ``safety_parts``. Returns
    the parts and the plant constants they read (``Controller.constants``)."""
    thermal, cut, _ = thermal_guard(ctx, temperature_budget_c(ctx, budget_c), band_c)
    parts = [*thermal, *safety_parts(ctx, demand, [cut] if cut else [])]
    return parts, observer_constants(ctx, thermal)
