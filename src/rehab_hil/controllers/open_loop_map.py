"""Open-loop PWM-ratio map of SMA bending (seed 000 sec B, Fig. 10): reference -> duty, no feedback.

At thermal equilibrium the bending angle rises about linearly with the PWM ratio between the
duty where bending starts (0.4) and full duty. Typed from the paper's figure, not computed from
the model: kept as the baseline a lab starts from (``bench/session_tracking.py``).
"""

from __future__ import annotations

from rehab_hil.config import Field, Section, model_validator
from rehab_hil.control.open_loop import DutyMap
from rehab_hil.controllers.base import ControlContext, Controller, ControllerSpec, Reference
from rehab_hil.controllers.limits import guarded

__all__ = ["OpenLoopMap", "OpenLoopMapSettings"]


class OpenLoopMapSettings(Section):
    effort_min: float = Field(ge=0.0, le=1000.0, description="effort where bending starts (Fig. 10: duty 0.4) "
                              "[actuator unit]")
    effort_max: float = Field(gt=0.0, le=1000.0, description="effort at the largest angle [actuator unit]")
    angle_min_deg: float = Field(ge=-360.0, le=360.0, description="angle at effort_min [deg]")
    angle_max_deg: float = Field(ge=-360.0, le=360.0, description="angle at effort_max (Fig. 7: 37.5 deg) [deg]")

    @model_validator(mode="after")
    def _rising(self) -> OpenLoopMapSettings:
        if not self.angle_max_deg > self.angle_min_deg:
            raise ValueError("angle_max_deg must exceed angle_min_deg")
        return self


class OpenLoopMap(ControllerSpec):
    """The reference mapped onto a one-sided drive (seed 000 Fig. 10)."""

    name = "open_loop_map"
    summary = "open-loop PWM-ratio map (seed 000 Fig. 10)"
    settings = OpenLoopMapSettings

    @classmethod
    def refuse(cls, ctx: ControlContext) -> str | None:
        if ctx.signed:
            return ("it maps the reference onto a one-sided drive held at equilibrium, and this actuator is "
                    f"signed ({ctx.effort}, an H-bridge): a held voltage runs the joint away")
        return None

    @classmethod
    def build(cls, ctx: ControlContext, settings: OpenLoopMapSettings, reference: Reference) -> Controller:
        demand = f"{ctx.effort}_demand"
        tail, constants = guarded(ctx, demand)
        parts = [reference.part(ctx.reference),
                 DutyMap("map", connect={"reference": ctx.reference}, rename={"effort": demand},
                         effort_min=settings.effort_min, effort_max=settings.effort_max,
                         angle_min_deg=settings.angle_min_deg, angle_max_deg=settings.angle_max_deg),
                 *tail]
        return Controller(cls.name, ctx, reference, parts, constants=constants, sums=(demand,))
