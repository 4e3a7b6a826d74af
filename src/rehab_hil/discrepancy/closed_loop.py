"""Closed-loop replay: a record made under feedback replayed from its reference.

A stiff loop hides a missing force in the output: the controller pushes the real axis onto the
reference whatever friction it meets, so the position barely differs, while the effort it needed
carries the whole discrepancy (EMPS: the nominal model without Coulomb friction replays the
position within 15 um and the drive input 0.59 V RMS off). Replaying the recorded effort open loop
lets an integrating model drift; replaying the loop from its reference, with the controller that
ran (``[recorded_controller]``, ``control/cascade.py``), keeps the model where the rig was and
compares both the output and the effort, each weighed by its spread (``Replay``).
"""

from __future__ import annotations

from typing import Any

import numpy as np

from rehab_hil.control.cascade import RecordedControllerSection
from rehab_hil.interchange import Recording

__all__ = ["describe_loop", "recorded_loop"]


def recorded_loop(cfg: Any, rec: Recording) -> RecordedControllerSection | None:
    """The config's recorded controller if the record carries its reference (in every row: a rig
    recording's stop rows have none, and the loop cannot be replayed from nothing) and its effort."""
    rc = getattr(cfg, "recorded_controller", None)
    if rc is None or rc.reference not in rec.signals or rc.effort not in rec.signals:
        return None
    if not np.all(np.isfinite(rec.signals[rc.reference])):
        return None
    return rc  # type: ignore[no-any-return]


def describe_loop(rc: RecordedControllerSection) -> str:
    """One line for the report: which controller closed the loop, from what, compared on what."""
    extra = f", plus {', '.join(rc.disturbances)} on the effort" if rc.disturbances else ""
    return (f"closed loop: {rc.kind} (kp {rc.kp_per_s:g} 1/s, kv {rc.kv_effort_s_per_unit:g}, +-{rc.saturation:g}) "
            f"from {rc.reference}{extra}; {rc.effort} compared as an output")
