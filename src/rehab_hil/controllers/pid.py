"""PID on the encoder angle: reference -> PID -> effort limit -> actuator (seed 002's position loop).

The one PID (``control/pid.py``) assembled once: offline it composes with the plant model, on the
rig the loop steps it with dt from device time. Its gains are in the actuator's unit per degree
(volts for the Finger Extensor, duty for an SMA wire) and live in ``[controllers.pid]``.
"""

from __future__ import annotations

from typing import Any

from rehab_hil.config import Field, Section
from rehab_hil.control.pid import PIDController
from rehab_hil.controllers.base import DT, ControlContext, Controller, ControllerSpec, Reference
from rehab_hil.controllers.limits import guarded, safety_parts

__all__ = ["PID", "PIDSettings", "feedback_parts", "limit_part", "needs_encoder"]


class PIDSettings(Section):
    """Gains in the actuator's unit (V, duty, W) per degree of the encoder angle."""

    kp_per_deg: float = Field(ge=0.0, le=1000.0, description="proportional gain [actuator unit / deg]")
    ki_per_deg_s: float = Field(ge=0.0, le=10000.0, description="integral gain [actuator unit / (deg s)]")
    kd_s_per_deg: float = Field(ge=0.0, le=100.0, description="derivative gain [actuator unit s / deg]")
    derivative_filter_s: float = Field(ge=0.0, le=1.0, description="derivative low-pass time constant [s]")
    temperature_budget_c: float | None = Field(default=None, gt=-50.0, le=1000.0, description="hottest the "
                                               "model's actuator may be held (heated actuators; default: the "
                                               "rig's temperature limit): a ceiling on the model's thermal part "
                                               "cuts the effort below it [C]")


def feedback_parts(ctx: ControlContext, gains: Any, demand: str, authority: tuple[float, float]) -> list:
    """The PID on the encoder angle, its output summed onto ``demand`` (its own clamp: ``authority``),
    its anti-windup reading the effort limit's saturation."""
    return [PIDController(
        "pid", connect={"reference": ctx.reference, "measurement": ctx.angle, "dt_s": DT,
                        "saturation": f"{ctx.effort}_saturation"},
        rename={"command": demand}, kp=gains.kp_per_deg, ki=gains.ki_per_deg_s, kd=gains.kd_s_per_deg,
        derivative_filter_s=gains.derivative_filter_s, output_min=authority[0], output_max=authority[1])]


def needs_encoder(ctx: ControlContext) -> str | None:
    """Why a controller on the encoder angle cannot run on this plant's rig, or None."""
    return None if ctx.binding.encoder_signal else "it needs an encoder, and the plant's rig has none"


def limit_part(ctx: ControlContext, demand: str, cut: str | None = None) -> list:
    """The last links before the actuator (``controllers.limits.safety_parts``): the heating guard
    and the demand clamped to what PWM may apply, cut by ``cut`` (a temperature ceiling's)."""
    return safety_parts(ctx, demand, [cut] if cut else [])


class PID(ControllerSpec):
    """Feedback only: the PID on the encoder angle tracks the reference."""

    name = "pid"
    summary = "PID on the encoder angle (feedback only)"
    settings = PIDSettings

    @classmethod
    def refuse(cls, ctx: ControlContext) -> str | None:
        return needs_encoder(ctx)

    @classmethod
    def build(cls, ctx: ControlContext, settings: PIDSettings, reference: Reference) -> Controller:
        demand = f"{ctx.effort}_demand"
        tail, constants = guarded(ctx, demand, settings.temperature_budget_c)
        parts = [reference.part(ctx.reference), *feedback_parts(ctx, settings, demand, ctx.effort_bounds), *tail]
        return Controller(cls.name, ctx, reference, parts, constants=constants, sums=(demand,))
