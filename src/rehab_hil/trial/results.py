"""``trial.json``: the trial's question, one entry per patient (the drawn parameters, per session the
measures the session report has, or the error), and the cohort's outcome in a few figures.

A patient "meets the target" when the last session's success of the moves the rig drives is at least
``target_success`` (assist-as-needed's own, 0.8) with no safety event and no error; the summary counts
the patients who do, per stratum as well. NaN is written as null (plain JSON, as a browser reads it).
"""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any

import numpy as np

from rehab_hil.outputs import replacing

__all__ = ["TRIAL_FILE", "last_session", "meets_target", "summary", "write_trial_json"]

TRIAL_FILE = "trial.json"


def last_session(entry: dict[str, Any]) -> dict[str, Any] | None:
    """The patient's last session that ran, or None (an error before the first)."""
    return entry["sessions"][-1] if entry.get("sessions") else None


def meets_target(entry: dict[str, Any], target: float) -> bool:
    """Every session ran, with no safety event, and the last one's driven moves succeeded at ``target``."""
    last = last_session(entry)
    if entry.get("error") or last is None or any(s["safety_events"] for s in entry["sessions"]):
        return False
    v = last.get("success_assisted")
    return v is not None and math.isfinite(v) and v >= target - 1e-9


def _median(values: list[Any]) -> float | None:
    v = [x for x in values if x is not None and math.isfinite(x)]
    return float(np.median(v)) if v else None


def _group(entries: list[dict[str, Any]], target: float) -> dict[str, Any]:
    """The figures of a group of patients (the cohort, a stratum)."""
    lasts = [last_session(e) for e in entries]
    ran = [s for s in lasts if s is not None]
    met = sum(meets_target(e, target) for e in entries)
    return {"patients": len(entries), "met": met, "met_share": met / len(entries) if entries else None,
            "errors": sum(1 for e in entries if e.get("error")),
            "with_safety_events": sum(1 for e in entries if any(s["safety_events"] for s in e["sessions"])),
            "median_success_assisted": _median([s.get("success_assisted") for s in ran]),
            "median_success_last5": _median([s.get("success_last5") for s in ran]),
            "median_success": _median([s.get("success") for s in ran]),
            "median_assistance_ratio_last": _median([s.get("assistance_ratio_last") for s in ran]),
            "max_peak_temperature_c": max((s["peak_temperature_c"] for s in ran
                                           if s.get("peak_temperature_c") is not None
                                           and math.isfinite(s["peak_temperature_c"])), default=None)}


def summary(entries: list[dict[str, Any]], target: float) -> dict[str, Any]:
    """The cohort's outcome, and per stratum."""
    strata = sorted({e["stratum"] for e in entries})
    return {"target_success": target, **_group(entries, target),
            "strata": {s: _group([e for e in entries if e["stratum"] == s], target) for s in strata}}


def _plain(v: Any) -> Any:
    """NaN and infinities as null, tuples as lists, numpy scalars as numbers (JSON that any reader takes)."""
    if isinstance(v, dict):
        return {str(k): _plain(x) for k, x in v.items()}
    if isinstance(v, list | tuple):
        return [_plain(x) for x in v]
    if isinstance(v, np.generic):
        v = v.item()
    if isinstance(v, float) and not math.isfinite(v):
        return None
    return v


def write_trial_json(path: str | Path, doc: dict[str, Any]) -> Path:
    """Write ``trial.json`` whole or not at all."""
    path = Path(path)
    with replacing(path) as tmp:
        tmp.write_text(json.dumps(_plain(doc), indent=1, allow_nan=False) + "\n", encoding="utf-8")
    return path
