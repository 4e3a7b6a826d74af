"""Tracking and step-response metrics (shared by simulate, the loop summary and discrepancy).

``recorded_tracking`` and ``recorded_step`` are a session's figures over its recorded rows: the
loop's summary and an analysis of run.csv / run.mcap (``rehab_hil.run_figures``) both call them, on
the same rows, so they give the same numbers."""

from __future__ import annotations

import numpy as np

__all__ = ["mae", "max_abs_error", "recorded_step", "recorded_tracking", "relative_error_pct", "rmse", "step_metrics",
           "tracking_metrics"]


def _pair(a: np.ndarray, b: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    a, b = np.asarray(a, float), np.asarray(b, float)
    if a.shape != b.shape or a.size == 0:
        raise ValueError(f"signals must be non-empty and of equal shape, got {a.shape} and {b.shape}")
    return a, b


def mae(reference: np.ndarray, actual: np.ndarray) -> float:
    r, a = _pair(reference, actual)
    return float(np.mean(np.abs(a - r)))


def rmse(reference: np.ndarray, actual: np.ndarray) -> float:
    r, a = _pair(reference, actual)
    return float(np.sqrt(np.mean((a - r) ** 2)))


def max_abs_error(reference: np.ndarray, actual: np.ndarray) -> float:
    r, a = _pair(reference, actual)
    return float(np.max(np.abs(a - r)))


def relative_error_pct(reference: np.ndarray, actual: np.ndarray) -> float:
    """Mean absolute error over the mean magnitude of the reference, in percent (seed 002 sec 4.2)."""
    r, a = _pair(reference, actual)
    scale = float(np.mean(np.abs(r)))
    return float("nan") if scale == 0.0 else 100.0 * float(np.mean(np.abs(a - r))) / scale


def tracking_metrics(reference: np.ndarray, actual: np.ndarray) -> dict[str, float]:
    return {
        "mae": mae(reference, actual),
        "rmse": rmse(reference, actual),
        "max_abs_error": max_abs_error(reference, actual),
        "relative_error_pct": relative_error_pct(reference, actual),
    }


def step_metrics(t: np.ndarray, y: np.ndarray, start: float, target: float,
                 settle_band: float = 0.02) -> dict[str, float]:
    """Rise time (10-90 %), overshoot past the target (signal units and %), settling time
    (last entry into +-``settle_band`` of the step size), and final error."""
    t, y = np.asarray(t, float), np.asarray(y, float)
    if t.shape != y.shape or t.size < 2:
        raise ValueError("t and y must be equal-length arrays of at least two samples")
    span = target - start
    if span == 0.0:
        raise ValueError("a step needs target != start")
    frac = (y - start) / span
    i10 = np.argmax(frac >= 0.1) if np.any(frac >= 0.1) else None
    i90 = np.argmax(frac >= 0.9) if np.any(frac >= 0.9) else None
    rise = float(t[i90] - t[i10]) if i10 is not None and i90 is not None else float("nan")
    reach = float(t[i90] - t[0]) if i90 is not None else float("nan")
    overshoot = max(0.0, float(np.max((y - target) * np.sign(span))))
    outside = np.abs(y - target) > settle_band * abs(span)
    if not outside.any():
        settling = 0.0
    elif outside[-1]:
        settling = float("nan")
    else:
        settling = float(t[np.nonzero(outside)[0][-1] + 1] - t[0])
    return {
        "rise_time_s": rise,
        "time_to_90pct_s": reach,
        "overshoot": overshoot,
        "overshoot_pct": 100.0 * overshoot / abs(span),
        "settling_time_s": settling,
        "final_error": float(y[-1] - target),
    }


def recorded_tracking(reference: np.ndarray, angle: np.ndarray) -> dict[str, float]:
    """``tracking_metrics`` over the rows that carry a reference (a recording's rows before the
    first command and after the stop carry none: NaN); {} when no row does."""
    r, a = np.asarray(reference, float), np.asarray(angle, float)
    ok = np.isfinite(r) & np.isfinite(a)
    return tracking_metrics(r[ok], a[ok]) if ok.any() else {}


def recorded_step(t: np.ndarray, reference: np.ndarray, angle: np.ndarray, start: float) -> dict[str, float]:
    """A step run's figures (``step_metrics``, the step at t = 0 from ``start`` to the reference's
    value) over the rows up to the last one with a reference (the stop's rows are not the
    response); {} when no row has one. Overshoot in the angle's unit and in % of the step."""
    t, r, a = (np.asarray(x, float) for x in (t, reference, angle))
    has = np.flatnonzero(np.isfinite(r))
    if has.size == 0 or r[has[-1]] == start:
        return {}
    keep = (t >= 0.0) & (np.arange(t.size) <= has[-1]) & np.isfinite(a)
    if keep.sum() < 2:
        return {}
    target = float(r[has[-1]])
    return {"target": target, "start": float(start), **step_metrics(t[keep], a[keep], start, target)}
