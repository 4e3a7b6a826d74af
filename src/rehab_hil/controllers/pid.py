"""PID on the encoder angle: reference -> PID -> effort limit -> actuator (seed 002's position loop).

The one PID (``control/pid.py``) assembled once: offline it composes with the plant model, on the
rig the loop steps it with dt from device time. Its gains are in the actuator's unit per degree
(volts for the Finger Extensor, duty for an SMA wire) and live in ``[controllers.pid]``.
"""

from __future__ import annotations

from typing import Any

from rehab_hil.config import Field, Section
from rehab_hil.control.limits import EffortLimit
from rehab_hil.control.pid import PIDController
from rehab_hil.controllers.base import DT, ControlContext, Controller, ControllerSpec, Reference

__all__ = ["PID", "PIDSettings", "feedback_parts"]


class PIDSettings(Section):
    """Gains in the actuator's unit (V, duty, W) per degree of the encoder angle."""

    kp_per_deg: float = Field(ge=0.0, le=1000.0, description="proportional gain [actuator unit / deg]")
    ki_per_deg_s: float = Field(ge=0.0, le=10000.0, description="integral gain [actuator unit / (deg s)]")
    kd_s_per_deg: float = Field(ge=0.0, le=100.0, description="derivative gain [actuator unit s / deg]")
    derivative_filter_s: float = Field(ge=0.0, le=1.0, description="derivative low-pass time constant [s]")


def feedback_parts(ctx: ControlContext, gains: Any, demand: str, authority: tuple[float, float]) -> list:
    """The PID on the encoder angle, its output summed onto ``demand`` (its own clamp: ``authority``),
    its anti-windup reading the effort limit's saturation."""
    return [PIDController(
        "pid", connect={"reference": ctx.reference, "measurement": ctx.angle, "dt_s": DT,
                        "saturation": f"{ctx.effort}_saturation"},
        rename={"command": demand}, kp=gains.kp_per_deg, ki=gains.ki_per_deg_s, kd=gains.kd_s_per_deg,
        derivative_filter_s=gains.derivative_filter_s, output_min=authority[0], output_max=authority[1])]


def limit_part(ctx: ControlContext, demand: str, cut: str | None = None) -> EffortLimit:
    """The last link before the actuator: the demand clamped to what PWM may apply."""
    lo, hi = ctx.effort_bounds
    return EffortLimit("limit", connect={"demand": demand, "cut": cut or []},
                       rename={"effort": ctx.effort, "saturation": f"{ctx.effort}_saturation"},
                       effort_min=lo, effort_max=hi)


class PID(ControllerSpec):
    """Feedback only: the PID on the encoder angle tracks the reference."""

    name = "pid"
    summary = "PID on the encoder angle (feedback only)"
    settings = PIDSettings

    @classmethod
    def refuse(cls, ctx: ControlContext) -> str | None:
        return None if ctx.binding.encoder_signal else "it needs an encoder, and the plant's rig has none"

    @classmethod
    def build(cls, ctx: ControlContext, settings: PIDSettings, reference: Reference) -> Controller:
        demand = f"{ctx.effort}_demand"
        parts = [reference.part(ctx.reference), *feedback_parts(ctx, settings, demand, ctx.effort_bounds),
                 limit_part(ctx, demand)]
        return Controller(cls.name, ctx, reference, parts, sums=(demand,))
