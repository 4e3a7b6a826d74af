"""The controller that produced a closed-loop record, to replay the loop on the model.

A proportional position loop around a proportional velocity loop (Janot, Gautier and Brunot 2019,
EMPS description eq 6): u = kp kv (q_r - q) - kv q', with the velocity from a two-tap FIR of the
position, q'(k) = (q_f(k) - q_f(k-1)) / dt, q_f(k) = (q(k) + q(k-1)) / 2, i.e.
(q(k) - q(k-2)) / (2 dt), and the output clipped to the drive's range. Declared in a plant config
as ``[recorded_controller]`` (``RecordedControllerSection``); the discrepancy workflow then replays
the record from its reference instead of its effort (docs/discrepancy.md, closed-loop replay).
"""

from __future__ import annotations

from typing import Literal

from rehab_hil.config import Field, Section
from rehab_hil.models.system import Part, njit

__all__ = ["LOOP_PREFIX", "PositionVelocityP", "RecordedControllerSection", "loop_parts"]

LOOP_PREFIX = "recorded_controller"  # parts of the replayed loop; their memory is set from the data


class RecordedControllerSection(Section):
    """``[recorded_controller]``: the controller that ran when the record was made."""

    kind: Literal["position_velocity_p"] = Field(description="position_velocity_p: EMPS eq 6, "
                                                 "u = kp kv (q_r - q) - kv q'")
    kp_per_s: float = Field(gt=0.0, le=1e5, description="position loop gain kp [1/s]")
    kv_effort_s_per_unit: float = Field(gt=0.0, le=1e7, description="velocity loop gain kv [effort unit per "
                                        "(position unit / s)], EMPS: V/(m/s)")
    saturation: float = Field(gt=0.0, le=1e6, description="the effort is clipped to +- this [effort unit]")
    sample_time_s: float = Field(gt=0.0, le=1.0, description="controller period (the FIR velocity's dt) [s]")
    reference: str = Field(min_length=1, description="recorded reference signal (a column), e.g. position_reference_m")
    feedback: str = Field(min_length=1, description="model signal fed back (the measured output), e.g. position_m")
    effort: str = Field(min_length=1, description="the plant input the controller drives (a recorded column, "
                        "compared as an output in the replay), e.g. drive_input_v")
    disturbances: list[str] = Field(default_factory=list, description="recorded signals added to the effort "
                                    "(EMPS validation run: its pulses enter the drive input beside the controller)")


class PositionVelocityP(Part):
    """EMPS eq 6 as a sampled part: reference and position in, effort out, two past positions held."""

    inputs = ("reference", "position")
    discrete_states = ("position_1", "position_2")
    outputs = ("effort",)
    params = ("kp_per_s", "kv", "saturation", "dt_s")
    feedthrough = ("reference", "position")

    @staticmethod
    @njit
    def output(t, x, xd, u, p, y):
        v = (u[1] - xd[1]) / (2.0 * p[3])
        e = p[0] * p[1] * (u[0] - u[1]) - p[1] * v
        y[0] = min(max(e, -p[2]), p[2])

    @staticmethod
    @njit
    def update(t, x, xd, u, p, xdn):
        xdn[1] = xd[0]
        xdn[0] = u[1]


def loop_parts(section: RecordedControllerSection, start_position: float) -> list[Part]:
    """The controller's parts: its effort (and any recorded disturbance) summed onto the plant input
    ``section.effort``; the FIR's memory starts at ``start_position`` (the record's first sample)."""
    parts: list[Part] = [PositionVelocityP(
        f"{LOOP_PREFIX}_{section.kind}", connect={"reference": section.reference, "position": section.feedback},
        rename={"effort": section.effort}, xd0=[start_position, start_position],
        kp_per_s=section.kp_per_s, kv=section.kv_effort_s_per_unit, saturation=section.saturation,
        dt_s=section.sample_time_s)]
    from rehab_hil.models.sensors import Gain

    for i, d in enumerate(section.disturbances):
        parts.append(Gain(f"{LOOP_PREFIX}_disturbance_{i}", connect={"u": d}, rename={"y": section.effort}, gain=1.0))
    return parts
