"""The therapist's measures in the report: per cycle of a session, and across sessions with a change
flagged only beyond its smallest real difference (``metadata.json`` ``session_cycles`` and ``session``,
``therapy_measures``)."""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from typing import Any

from rehab_hil.report.page import table

__all__ = ["SRD_SHARE", "changes", "cycle_table", "session_table"]

# smallest real difference of the robotic finger assessments, as a share of the value (Zbytniewska et al.,
# JNER 2021: ICC > 0.7, SRD < 30 %): a change between two sessions smaller than this is not flagged
SRD_SHARE = 0.30

_CYCLE = (("success", "success [share]"), ("success_assisted", "success, moves the rig drives [share]"),
          ("assistance_ratio", "assistance ratio"),
          ("active_rom_deg", "active ROM [deg]"), ("peak_velocity_deg_s", "peak velocity [deg/s]"),
          ("sparc", "SPARC"), ("ldlj", "LDLJ"),
          ("patient_torque_open_nm", "patient torque, opening, torque sensor [N m]"),
          ("patient_torque_close_nm", "patient torque, closing, torque sensor [N m]"),
          ("patient_torque_open_model_nm", "patient torque, opening, {source} [N m]"),
          ("patient_torque_close_model_nm", "patient torque, closing, {source} [N m]"),
          ("interaction_stiffness_nm_per_rad", "interaction stiffness [N m/rad]"),
          ("resistance_slope_nm_s_per_rad", "velocity-dependent resistance [N m s/rad]"))
_SESSION = (("success", "success rate"), ("success_assisted", "success rate, moves the rig drives"),
            ("assistance_ratio", "assistance ratio"), ("rom_deg", "ROM [deg]"),
            ("peak_velocity_deg_s", "peak velocity [deg/s]"), ("sparc", "SPARC"),
            ("patient_torque_open_nm", "patient torque, opening [N m]"),
            ("patient_torque_open_model_nm", "patient torque, opening, model [N m]"))


def cycle_table(cycles: Sequence[Mapping[str, Any]]) -> str | None:
    """The per-cycle table, or None when the session has no therapist's measures (an older run)."""
    if not cycles or "success" not in cycles[0]:
        return None
    keys = [(k, h) for k, h in _CYCLE if any(_finite(c.get(k)) for c in cycles)]
    source = next((c["patient_torque_model_source"] for c in cycles if c.get("patient_torque_model_source")), "model")
    return table(["cycle", *(h.format(source=source) for _, h in keys)],
                 [[int(c["index"]), *(_cell(c, k) for k, _ in keys)] for c in cycles])


def _cell(cycle: Mapping[str, Any], key: str) -> Any:
    """A measure's value, with its 95 % half-interval where it has one (the patient's torque: "0.21 ± 0.01")."""
    v, ci = cycle.get(key), cycle.get(key.removesuffix("_nm") + "_ci_nm")
    return f"{v:.3g} ± {ci:.2g}" if _finite(v) and _finite(ci) else v


def _finite(v: Any) -> bool:
    return isinstance(v, int | float) and math.isfinite(v)


def changes(before: Mapping[str, Any], after: Mapping[str, Any]) -> list[str]:
    """The measures that changed by more than ``SRD_SHARE`` of their earlier value between two sessions."""
    out = []
    for key, label in _SESSION:
        a, b = before.get(key), after.get(key)
        if _finite(a) and _finite(b) and abs(b - a) > SRD_SHARE * max(abs(a), 1e-9):
            out.append(f"{label} {'up' if b > a else 'down'}")
    return out


def session_table(labels: Sequence[str], sessions: Sequence[Mapping[str, Any]]) -> str | None:
    """Across sessions: each session's measures and the changes beyond the smallest real difference."""
    if not any("success" in s for s in sessions):
        return None
    rows = []
    for i, (label, s) in enumerate(zip(labels, sessions, strict=True)):
        flagged = ", ".join(changes(sessions[i - 1], s)) if i else ""
        rows.append([label, *(s.get(k) for k, _ in _SESSION), flagged or "–"])
    return table(["run", *(h for _, h in _SESSION), f"changed beyond {SRD_SHARE:.0%} (SRD)"], rows)
