"""Assist-as-needed: the feedback's authority learned across cycles, per direction, holding a target
success rate (``control/assist.py``: Emken et al. 2007, with FINGER's success target; Wolbrecht et al.
2008's integral of the tracking error as the headroom).

    reference -> PID on the angle -> x assistance(direction) (+ the headroom's integral) -> limits -> actuator

The assistance of each direction is learned once per move: up where the patient failed to reach the
target in time, down where they succeeded, its fixed point the target success rate; in a run of
successes longer than the target allows it is also forgotten, and a failure gives that back. Below
``1 - integral_headroom`` it scales the feedback; above, the feedback is at its full gains and an
integral of the error in each move's hold adds what a stiff or weak finger needs beyond it. Never beyond
the chain's own limits (``controllers/limits.py``: the heating guard,
the temperature ceiling, the effort clamp). Where the actuator pulls one way only (an SMA wire, a TCP
muscle: unsigned effort) the other direction's move is the spring's and the finger's, and only the
pulling direction's assistance is learned; it scales each pull of the actuator, whatever the move.
``baseline`` is the same chain at full assistance with nothing learned: its energy on the host's
model (a passive finger) is the assistance ratio's denominator (``therapy_measures``).
"""

from __future__ import annotations

from rehab_hil.config import Field, Section
from rehab_hil.control.assist import AssistScale, streak_moves
from rehab_hil.controllers.base import DT, ControlContext, Controller, ControllerSpec, Reference
from rehab_hil.controllers.limits import guarded
from rehab_hil.controllers.pid import feedback_parts, needs_encoder
from rehab_hil.therapy_measures import SUCCESS_WINDOW_S, success_tolerance_deg

__all__ = ["ASSIST_PART", "AssistAsNeeded", "AssistAsNeededSettings", "learned_directions"]

ASSIST_PART = "assistance"  # the scale's part name: its states assist_open, assist_close


class AssistAsNeededSettings(Section):
    """The feedback's gains (the actuator's unit per degree, as ``[controllers.pid]``) and the learning."""

    kp_per_deg: float = Field(ge=0.0, le=1000.0, description="proportional gain [actuator unit / deg]")
    ki_per_deg_s: float = Field(default=0.0, ge=0.0, le=10000.0, description="integral gain [actuator unit / (deg s)]")
    kd_s_per_deg: float = Field(default=0.0, ge=0.0, le=100.0, description="derivative gain [actuator unit s / deg]")
    derivative_filter_s: float = Field(default=0.01, ge=0.0, le=1.0, description="derivative low-pass [s]")
    target_success: float = Field(default=0.8, ge=0.5, le=0.95, description="share of moves that should reach "
                                  "their target (FINGER: 0.82 high, 0.55 low assistance; Rowe et al. 2017)")
    gain_per_move: float = Field(default=0.4, gt=0.0, le=1.0, description="assistance step per move [0..1]")
    forgetting_per_move: float = Field(default=0.1, ge=0.0, lt=1.0, description="share of the assistance "
                                       "forgotten after a move done with margin in a run of more successes than "
                                       "the target's T / (1 - T), given back at the next failure (Emken et al. "
                                       "2007's 1 - f_R)")
    initial_assistance: float = Field(default=1.0, ge=0.0, le=1.0, description="the first cycle's assistance "
                                      "(1 - integral_headroom: the feedback at its full gains, no integral)")
    integral_headroom: float = Field(default=0.0, ge=0.0, le=0.9, description="the top share of the assistance "
                                     "range that adds integral action once the feedback is at its full gains "
                                     "(Wolbrecht et al. 2008; 0: none) [share of the range]")
    headroom_ki_per_deg_s: float = Field(default=0.0, ge=0.0, le=10000.0, description="the headroom's integral "
                                         "gain at full assistance, restarted each move [actuator unit / (deg s)]")
    min_assistance: float = Field(default=0.0, ge=0.0, le=1.0, description="never below this [0..1]")
    temperature_budget_c: float | None = Field(default=None, gt=-50.0, le=1000.0, description="hottest the model's "
                                               "actuator may be held (heated actuators; default: the rig's limit) [C]")


class AssistAsNeeded(ControllerSpec):
    """PID feedback scaled by an assistance learned per direction across cycles."""

    name = "assist_as_needed"
    summary = "PID scaled by assistance learned per direction across cycles (assist-as-needed)"
    settings = AssistAsNeededSettings

    @classmethod
    def refuse(cls, ctx: ControlContext) -> str | None:
        return needs_encoder(ctx)

    @classmethod
    def build(cls, ctx: ControlContext, settings: AssistAsNeededSettings, reference: Reference) -> Controller:
        built = cls._chain(ctx, settings, reference, learn=True)
        built.baseline = cls._chain(ctx, settings, reference, learn=False) if reference.kind == "session" else None
        return built

    @classmethod
    def _chain(cls, ctx: ControlContext, s: AssistAsNeededSettings, ref: Reference, learn: bool) -> Controller:
        demand, command = f"{ctx.effort}_demand", f"{ctx.effort}_feedback"
        tail, constants = guarded(ctx, demand, s.temperature_budget_c)
        # the baseline (the assistance ratio's denominator) is the feedback at its full gains, no headroom
        a0 = s.initial_assistance if learn else 1.0 - s.integral_headroom
        # the direction the actuator pulls: a signed one both; an unsigned one raises the angle (the bend)
        pulls_open, pulls_close = True, ctx.signed
        scale = AssistScale(
            ASSIST_PART, connect={"command": command, "measurement": ctx.angle, "dt_s": DT,
                                  "reference": ctx.reference, "saturation": f"{ctx.effort}_saturation"},
            rename={"demand": demand},
            xd0=[0.0, a0, a0 if pulls_close else 1.0, 0, 0, 0, 0, 0, 0, 0, 0, 0, -2.0, -1.0, -1.0],
            closed=ref.closed_deg, opened=ref.open_deg, move_s=ref.move_s, hold_open_s=ref.hold_open_s,
            hold_closed_s=ref.hold_closed_s, first_open_s=ref.first_open_s,
            tolerance=success_tolerance_deg(ref.closed_deg, ref.open_deg, ctx.binding.encoder_count_deg),
            window_s=SUCCESS_WINDOW_S,
            gain=s.gain_per_move, forgetting=s.forgetting_per_move, target_success=s.target_success,
            min_assistance=s.min_assistance, max_assistance=1.0,
            learn_open=1.0 if learn and pulls_open and ref.kind == "session" else 0.0,
            learn_close=1.0 if learn and pulls_close and ref.kind == "session" else 0.0,
            one_way=0.0 if pulls_close else 1.0, streak_moves=streak_moves(s.target_success),
            headroom=s.integral_headroom, ki=s.headroom_ki_per_deg_s)
        parts = [ref.part(ctx.reference), *feedback_parts(ctx, s, command, ctx.effort_bounds), scale, *tail]
        return Controller(cls.name, ctx, ref, parts, constants=constants, sums=(demand,))


def learned_directions(controller: Controller) -> dict[str, str]:
    """{"open" / "close": the qualified state holding that direction's assistance} for each direction
    a built controller learns across cycles ({} for any other controller, or a step reference)."""
    for part in controller.parts:
        if isinstance(part, AssistScale) and part.name == ASSIST_PART:
            p = dict(zip(part.params, part.param_values, strict=True))
            return {d: f"{ASSIST_PART}.assist_{d}" for d in ("open", "close") if p[f"learn_{d}"] > 0.5}
    return {}
