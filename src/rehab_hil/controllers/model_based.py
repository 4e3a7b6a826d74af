"""Model-based tracking: feedforward learned on the plant model + PID feedback + (for a heated
actuator) the model's thermal part as an observer and a temperature ceiling -> effort limit.

    reference --> feedforward table (ILC on the model) --+
              \\                                          +--> demand --> limit --> actuator
               +--> PID on the encoder angle ------------+         ^
    observer (the model's thermal part on the applied effort) --> ceiling (cut)

The feedforward comes from the composed plant model, ``[[effects]]`` included
(``controllers/feedforward.py``), never from numbers in a config: ``augmented.toml`` from the
discrepancy workflow changes it by itself. The reference is first clipped to what the model can
hold (``controllers/reachable.py``). For an SMA wire or a TCP coil, which only heat and cool
passively, the learned table heats ahead of the bend and lets the wire cool ahead of the release;
the ceiling keeps the observed temperature under the plan's peak plus a margin (the feedback may
not heat further than the bend needs), and the PID's integrator stops while the limit or the
ceiling cuts its demand (anti-windup).
"""

from __future__ import annotations

from typing import Any

import numpy as np

from rehab_hil.config import Field, Section
from rehab_hil.controllers.base import ControlContext, Controller, ControllerSpec, Plan, Reference, closed_loop_system
from rehab_hil.controllers.feedforward import LearningSettings, cached, fingerprint, learn
from rehab_hil.controllers.limits import (
    HEATING_REST_S,
    heating_limit_s,
    observer_constants,
    safety_parts,
    temperature_budget_c,
    thermal_guard,
)
from rehab_hil.controllers.pid import PID, feedback_parts
from rehab_hil.controllers.reachable import reachable_range
from rehab_hil.controllers.rig_learning import RigLearningSpec
from rehab_hil.models.sensors import Gain
from rehab_hil.progress import announce

__all__ = ["ModelBased", "ModelBasedSettings"]

_PERIODS = 2  # a periodic table learns on two cycles from rest: the second is the steady state
PLAN_VERSION = 3  # part of the cache key: bump when the learning or the chain changes what a plan is
# config tables a plan does not depend on, left out of its cache key (editing the twin's settings or an
# import mapping relearned every plan; a host model never applies [[changes]], the simulated rig's schedule)
NOT_IN_PLAN = ("twin", "import_", "recorded_controller", "changes")
RIG_ONLY = ("rig_learning", "rig_learning_gain_per_deg", "rig_learning_forgetting")  # settings of the learning on the
#                                                                                     rig, not of the model's plan


class ModelBasedSettings(Section):
    """Feedback gains around the learned feedforward, and how the feedforward is learned."""

    kp_per_deg: float = Field(ge=0.0, le=1000.0, description="feedback proportional gain [actuator unit / deg]")
    ki_per_deg_s: float = Field(ge=0.0, le=10000.0, description="feedback integral gain [actuator unit / (deg s)]")
    kd_s_per_deg: float = Field(ge=0.0, le=100.0, description="feedback derivative gain [actuator unit s / deg]")
    derivative_filter_s: float = Field(ge=0.0, le=1.0, description="derivative low-pass time constant [s]")
    learning_gain_per_deg: float = Field(gt=0.0, le=1000.0, description="ILC gain: feedforward change per degree "
                                         "of error [actuator unit / deg]")
    learning_lead_s: float = Field(ge=0.0, le=10.0, description="ILC lead: the error this much later moves the "
                                   "feedforward now (the plant's lag) [s]")
    learning_release_lead_s: float | None = Field(default=None, ge=0.0, le=10.0, description="ILC lead for "
                                                  "errors the effort must drop to fix (a heated actuator cools "
                                                  "passively, slower than it heats) [s]; unset: learning_lead_s")
    learning_filter_hz: float = Field(gt=0.0, le=200.0, description="ILC Q-filter cutoff (zero phase) [Hz]")
    learning_iterations: int = Field(ge=1, le=1000, description="ILC trials on the model")
    learning_leak: float = Field(ge=0.0, lt=1.0, description="ILC pull of the feedforward toward zero per "
                                 "trial where the error is within tolerance (least effort that tracks) [0..1)")
    learning_tolerance_deg: float = Field(default=0.25, gt=0.0, le=10.0, description="error the leak accepts "
                                          "[deg]")
    temperature_budget_c: float | None = Field(default=None, gt=-50.0, le=1000.0, description="hottest the "
                                               "model's actuator may be held (heated actuators; default: the "
                                               "rig's temperature limit): the reference is clipped to what the "
                                               "model reaches within it, and the ceiling never exceeds it [C]")
    temperature_margin_c: float = Field(default=10.0, gt=0.0, le=100.0, description="ceiling above the plan's "
                                        "peak observed temperature (heated actuators) [C]")
    ceiling_band_c: float = Field(default=5.0, gt=0.0, le=50.0, description="the ceiling cuts the authority "
                                  "linearly over this band below it [C]")
    rig_learning: bool = Field(default=False, description="keep learning the feedforward on the rig, cycle after "
                               "cycle, from the measured tracking error (controllers/rig_learning.py)")
    rig_learning_gain_per_deg: float | None = Field(default=None, gt=0.0, le=1000.0, description="the rig's ILC "
                                                    "gain [actuator unit / deg]; unset: learning_gain_per_deg")
    rig_learning_forgetting: float = Field(default=0.02, ge=0.0, lt=1.0, description="share of the correction "
                                           "learned on the rig forgotten per cycle, toward the model's table [0..1)")


class ModelBased(ControllerSpec):
    name = "model_based"
    summary = "feedforward learned on the model + PID feedback (+ thermal observer and ceiling)"
    settings = ModelBasedSettings

    refuse = PID.refuse  # the same feedback on the encoder angle: the same requirement

    @classmethod
    def build(cls, ctx: ControlContext, settings: ModelBasedSettings, reference: Reference) -> Controller:
        notes: list[str] = []
        limit_c = temperature_budget_c(ctx, settings.temperature_budget_c)
        lo, hi = reachable_range(ctx, limit_c)
        reference, warning = reference.clipped(lo, hi)
        if warning:
            notes.append(warning)
        periodic = reference.kind == "session"
        periods = _PERIODS if periodic else 1
        n = ctx.plant.n_steps(ctx.cfg, reference.period_s)  # the table: one period (a step: one horizon)
        ff = f"{ctx.effort}_feedforward"

        def make(table: np.ndarray, ceiling_c: float, plan_extra: dict[str, Any] | None = None) -> Controller:
            demand = f"{ctx.effort}_demand"
            span = ctx.effort_bounds[1] - ctx.effort_bounds[0]
            thermal, cut, _ = thermal_guard(ctx, ceiling_c, settings.ceiling_band_c)
            parts = [reference.part(ctx.reference),
                     Gain("feedforward", connect={"u": ff}, rename={"y": demand}, gain=1.0),
                     *feedback_parts(ctx, settings, demand, (-span, span)), *thermal,
                     *safety_parts(ctx, demand, [cut] if cut else [])]
            extra = plan_extra or {}
            plan = Plan(ctx.step_s, reference.period_s if periodic else ctx.step_s, {ff: table},
                        extra.get("predicted", {}),
                        extra.get("figures", {}), extra.get("key", ""))
            return Controller(cls.name, ctx, reference, parts, plan=plan, constants=observer_constants(ctx, thermal),
                              sums=(demand,), notes=notes, rig_learning=extra.get("rig_learning"))

        _, _, t_obs = thermal_guard(ctx, limit_c, settings.ceiling_band_c)
        not_in_plan: dict[str, Any] = {**dict.fromkeys(NOT_IN_PLAN, True),
                                       "controllers": {cls.name: set(RIG_ONLY)}}
        key = fingerprint("model_based", PLAN_VERSION, ctx.cfg.model_dump(exclude=not_in_plan),
                          settings.model_dump(exclude=set(RIG_ONLY)), reference, reference.first_open_s, periods)
        learned = cached("plans", key, lambda: _announced_learn(make(np.zeros(n), limit_c), n, periods, settings,
                                                                t_obs))
        ceiling_c = limit_c
        if t_obs is not None:
            ceiling_c = min(float(learned["peak_observed_c"][0]) + settings.temperature_margin_c, limit_c)
        figures = {k: float(learned[k][0]) for k in ("model_rmse_deg", "model_max_error_deg", "model_first_rmse_deg",
                                                     "model_first_max_error_deg", "trials", "peak_observed_c")}
        predicted = {"angle_deg": learned["angle_deg"], "effort": learned["effort"]}
        if t_obs is not None:
            predicted["temperature_c"] = learned["temperature_c"]
        spec = _rig_learning(ctx, settings, reference, limit_c, key) if periodic else None
        return make(learned["feedforward"], ceiling_c, {"predicted": predicted, "key": key, "rig_learning": spec,
                                                        "figures": {**figures, "ceiling_c": ceiling_c,
                                                                    "reachable_lo_deg": lo,
                                                                    "reachable_hi_deg": hi}})


def _learning_settings(settings: ModelBasedSettings) -> LearningSettings:
    return LearningSettings(settings.learning_gain_per_deg, settings.learning_lead_s, settings.learning_filter_hz,
                            settings.learning_iterations, settings.learning_leak, settings.learning_tolerance_deg,
                            settings.learning_release_lead_s)


def _rig_learning(ctx: ControlContext, settings: ModelBasedSettings, reference: Reference, budget_c: float,
                  key: str) -> RigLearningSpec:
    """How the plan keeps learning on the rig: the model learning's step, the rig's gain and
    forgetting, the envelope (effort bounds, heating limit, the budget on the observer)."""
    thermal, _, t_obs = thermal_guard(ctx, budget_c, settings.ceiling_band_c)
    observer = thermal[:-1]  # without the ceiling: the model's thermal part alone
    model = _learning_settings(settings)
    # the rig's step: the model's leads and Q-filter, no leak (the forgetting pulls toward the model's table,
    # which already holds the least effort that tracks; a leak on the rig drifts the nominal rig's table)
    rig = LearningSettings(model.gain_per_deg, model.lead_s, model.filter_hz, 1, 0.0, model.tolerance_deg,
                           model.release_lead_s)
    return RigLearningSpec(
        learning=rig,
        gain_per_deg=settings.rig_learning_gain_per_deg or settings.learning_gain_per_deg,
        forgetting=settings.rig_learning_forgetting, bounds=ctx.effort_bounds, step_s=ctx.step_s,
        period_s=reference.period_s, swap_s=0.5 * reference.hold_closed_s, heating_limit_s=heating_limit_s(ctx),
        rest_s=HEATING_REST_S, budget_c=budget_c if t_obs else None, observer=observer, effort=ctx.effort,
        temperature=t_obs or "", constants=observer_constants(ctx, observer), plan_key=key,
        enabled=settings.rig_learning, deadband_deg=360.0 / ctx.binding.encoder_counts_per_rev)


def _announced_learn(provisional: Controller, n: int, periods: int, settings: ModelBasedSettings,
                     t_obs: str | None) -> dict[str, np.ndarray]:
    """``_learn``, saying so when it takes a while (once per plan: the result is cached)."""
    with announce(f"learning the feedforward plan on the model ({settings.learning_iterations} trials at most, "
                  "once per config and reference, then cached)"):
        return _learn(provisional, n, periods, settings, t_obs)


def _learn(provisional: Controller, n: int, periods: int, settings: ModelBasedSettings,
           t_obs: str | None) -> dict[str, np.ndarray]:
    """Learn the feedforward on the closed loop of the provisional controller (ceiling at the rig's
    limit), then run the best table once more for the model's predictions (its last period)."""
    ctx = provisional.ctx
    system, feed = closed_loop_system(provisional)
    given = {k: v for k, v in feed(n * periods).items() if k in system.input_names}
    ff = next(iter(provisional.plan.signals)) if provisional.plan else ""
    outs = [ctx.reference, ctx.angle, ctx.effort, *([t_obs] if t_obs else [])]

    def run(u: np.ndarray) -> Any:
        return system.simulate(n * periods, {**given, ff: u}, outputs=outs)

    def simulate(u: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        r = run(u)
        return r[ctx.reference], r[ctx.angle]

    table, figures = learn(simulate, n, ctx.step_s, ctx.effort_bounds, _learning_settings(settings), periods)
    final = run(np.tile(table, periods))
    peak = float(np.max(final[t_obs])) if t_obs else float("nan")
    out = {"feedforward": table, "angle_deg": final[ctx.angle][-n:], "effort": final[ctx.effort][-n:],
           "peak_observed_c": np.array([peak]), **{k: np.array([v]) for k, v in figures.items()}}
    if t_obs:
        out["temperature_c"] = final[t_obs][-n:]
    return out
