"""Pulsed actuation (seed 001 sec 3.1, PIS): a fixed effort for ``on_s``, then rest for ``off_s``.

No feedback and no model: the TCP finger's session before model-based control, and a bring-up
drive. On a signed actuator (a motor behind an H-bridge) every other pulse runs reversed, so the
joint goes out and back. The session's reference is recorded beside it for the tracking figures.
"""

from __future__ import annotations

from rehab_hil.config import Field, Section
from rehab_hil.control.open_loop import PulseTrain
from rehab_hil.controllers.base import ControlContext, Controller, ControllerSpec, Reference
from rehab_hil.controllers.limits import guarded

__all__ = ["Pulsed", "PulsedSettings"]


class PulsedSettings(Section):
    effort: float = Field(ge=0.0, le=1000.0, description="effort while on [actuator unit: duty, W or V]")
    on_s: float = Field(gt=0.0, le=600.0, description="pulse length [s]")
    off_s: float = Field(ge=0.0, le=600.0, description="rest between pulses [s]")


class Pulsed(ControllerSpec):
    name = "pulsed"
    summary = "open-loop pulses (seed 001 PIS)"
    settings = PulsedSettings

    @classmethod
    def build(cls, ctx: ControlContext, settings: PulsedSettings, reference: Reference) -> Controller:
        demand = f"{ctx.effort}_demand"
        tail, constants = guarded(ctx, demand)
        parts = [reference.part(ctx.reference),
                 PulseTrain("pulses", rename={"effort": demand}, effort=settings.effort, on_s=settings.on_s,
                            off_s=settings.off_s, alternate=1.0 if ctx.signed else 0.0),
                 *tail]
        return Controller(cls.name, ctx, reference, parts, constants=constants, sums=(demand,))
