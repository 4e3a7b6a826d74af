"""What the trial keeps of one session: the one place that reads the session's result.

The session (``service/session.py``: ``RunResult``) is being restructured; ``session_measures`` is the
only function of the trial that knows its shape, so a change there is adapted here alone.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

__all__ = ["LAST_CYCLES", "session_measures"]

LAST_CYCLES = 5  # success_last5: the moves the rig drives over the last five cycles (issue 48)


def session_measures(session: Any) -> dict[str, Any]:
    """The figures of a session that has run (a ``RigSession`` after ``run``: its ``result``, the
    ``RunResult``, and its ``run_dir``) that the trial reports, SI units in the keys:
    success of both moves and of the moves the rig drives (``success_assisted``; over the last five
    cycles ``success_last5``), the assistance ratio (session mean, first and last cycle, per cycle), the
    active range of motion, SPARC, the patient's torque per move direction (the torque sensor's, and the
    twin's model-based estimate where the twin ran), the hottest cycle's peak temperature, the safety
    events, how the session ended, the assistance kept across sessions (where it started and ended) and
    the run directory."""
    result = session.result
    cycles = list(result.session_cycles)
    figures = dict(result.session)

    def per_cycle(key: str) -> list[float]:
        return [float(c.get(key, math.nan)) for c in cycles]

    def mean(values: list[float]) -> float:
        v = np.asarray(values, float)
        return float(np.nanmean(v)) if np.isfinite(v).any() else math.nan

    ratios = per_cycle("assistance_ratio")
    driven = per_cycle("success_assisted")
    out: dict[str, Any] = {
        "run_dir": None if session.run_dir is None else str(session.run_dir),
        "cycles": len(cycles),
        "stop_reason": result.stop_reason,
        "ran_s": float(result.ran_s),
        "success": float(figures.get("success", math.nan)),
        "success_assisted": float(figures.get("success_assisted", math.nan)),
        "success_last5": mean(driven[-LAST_CYCLES:]),
        "assistance_ratio": float(figures.get("assistance_ratio", math.nan)),
        "assistance_ratio_first": ratios[0] if ratios else math.nan,
        "assistance_ratio_last": ratios[-1] if ratios else math.nan,
        "assistance_ratio_per_cycle": ratios,
        "success_assisted_per_cycle": driven,
        "active_rom_deg": mean(per_cycle("active_rom_deg")),
        "sparc": float(figures.get("sparc", math.nan)),
        "rmse_deg": float(figures.get("rmse_deg", math.nan)),
        "peak_temperature_c": float(figures.get("peak_temperature_c", math.nan)),
        "safety_events": [{"t_s": float(e.t_s), "reason": e.reason, "detail": e.detail} for e in result.events],
    }
    for key in ("patient_torque_open_nm", "patient_torque_close_nm",
                "patient_torque_open_model_nm", "patient_torque_close_model_nm"):
        out[key] = float(figures.get(key, math.nan))
    kept = result.assistance or {}
    out["assistance_start"] = kept.get("start")
    out["assistance_end"] = kept.get("end")
    out["assistance_resumed"] = kept.get("resumed")
    return out
