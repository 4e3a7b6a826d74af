"""Feedforward from the plant model: iterative learning control (ILC) on the simulated closed loop.

The controller's own parts (reference, feedback, observer, limits) are composed with the plant
model, the config's ``[[effects]]`` included, and the feedforward table is learned on that
diagram, trial after trial, as ILC learns on a repeating task (Bristow, Tharayil and Alleyne,
"A survey of iterative learning control", IEEE Control Systems 26(3), 2006): each trial runs the
whole horizon, and the table moves by the tracking error a lead time later,

    u_{j+1}(t) = clip( Q[ u_j(t) + gamma e_j(t + lead) - leak u_j(t) [|e_j(t + lead)| < tol] ], lo, hi )

with Q a zero-phase low-pass (scipy ``filtfilt``), so the learning never amplifies noise-like
content the plant cannot follow. The lead covers the plant's lag (a wire's heating, a motor's
inertia); the leak pulls the effort toward zero wherever the error is within tolerance, so an
SMA wire is held just as warm as the bend needs (its hysteresis makes warmer invisible to the
error), without the steady bias a plain forgetting factor leaves where effort is needed.
Nothing here knows a plant: a corrected parameter or a fitted effect in ``augmented.toml``
changes the learned table by itself. The best trial is kept; the table is cached on disk, keyed
by everything it depends on.
"""

from __future__ import annotations

import hashlib
import json
import os
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from rehab_hil.models.engine import cache_dir

__all__ = ["LearningSettings", "cached", "ilc_step", "learn"]


class LearningSettings:
    """ILC settings: gain [effort per deg], lead [s], Q-filter cutoff [Hz], trials, leak per trial."""

    def __init__(self, gain_per_deg: float, lead_s: float, filter_hz: float, iterations: int, leak: float,
                 tolerance_deg: float = 0.25, release_lead_s: float | None = None) -> None:
        self.gain_per_deg, self.lead_s, self.filter_hz = gain_per_deg, lead_s, filter_hz
        self.iterations, self.leak, self.tolerance_deg = int(iterations), leak, tolerance_deg
        self.release_lead_s = lead_s if release_lead_s is None else release_lead_s


def learn(simulate: Callable[[np.ndarray], tuple[np.ndarray, np.ndarray]], n: int, step_s: float,
          bounds: tuple[float, float], s: LearningSettings, periods: int = 1) -> tuple[np.ndarray, dict[str, float]]:
    """The feedforward table that makes ``simulate(u) -> (reference, angle)`` track.

    ``periods`` > 1: the table is one period of ``n`` steps, repeated ``periods`` times from rest;
    it learns from the last period (the periodic steady state), with the lead and the Q-filter
    wrapping around the period, so the heating ahead of the next cycle's bend is learned from that
    bend. ``periods`` = 1: a table over a horizon of ``n`` steps (a step response). Returns the best
    trial and its figures on the learned period (RMSE, max error) and on the first, from rest."""
    periodic = periods > 1
    u = np.zeros(n)
    best: tuple[float, np.ndarray, dict[str, float]] = (np.inf, u.copy(), {})
    for _ in range(max(1, s.iterations)):
        ref, y = simulate(np.tile(u, periods) if periodic else u)
        e_all = ref - y
        e = e_all[-n:]
        rmse = float(np.sqrt(np.mean(e**2)))
        if rmse < best[0]:
            first = e_all[:n]
            best = (rmse, u.copy(), {"model_rmse_deg": rmse, "model_max_error_deg": float(np.max(np.abs(e))),
                                     "model_first_rmse_deg": float(np.sqrt(np.mean(first**2))),
                                     "model_first_max_error_deg": float(np.max(np.abs(first)))})
        u = ilc_step(u, e, step_s, bounds, s, periodic)
    return best[1], {**best[2], "trials": float(max(1, s.iterations))}


def ilc_step(u: np.ndarray, e: np.ndarray, step_s: float, bounds: tuple[float, float], s: LearningSettings,
             periodic: bool, gain_per_deg: float | None = None) -> np.ndarray:
    """One ILC trial's update: the table ``u`` moved by the error ``e`` (reference - angle, one
    value per table row) a lead later, the leak where within tolerance, the zero-phase Q-filter
    (wrapped around a period when ``periodic``) and the clip to ``bounds``. The model learning and
    the learning on the rig (``controllers/rig_learning.py``) take the same step; the rig's own
    gain is ``gain_per_deg`` (default: ``s.gain_per_deg``)."""
    from scipy.signal import butter, filtfilt  # 1.1 s of import: only when a feedforward is learned

    n = len(u)
    gain = s.gain_per_deg if gain_per_deg is None else gain_per_deg
    lead = max(0, round(s.lead_s / step_s))
    release = max(0, round(s.release_lead_s / step_s))
    b, a = butter(2, min(s.filter_hz * 2.0 * step_s, 0.99))
    shifted = _ahead(e, lead, periodic)
    if release != lead:  # too far along: the effort must drop this much earlier (a wire cools slower)
        back = _ahead(e, release, periodic)
        shifted = np.where(back < 0.0, np.minimum(shifted, back), np.maximum(shifted, 0.0))
    # the leak acts only where tracking is within tolerance: it finds the least effort that
    # still tracks without biasing the error where the effort is needed
    v = u + gain * shifted - s.leak * u * (np.abs(shifted) < s.tolerance_deg)
    v = filtfilt(b, a, np.tile(v, 3))[n:2 * n] if periodic else filtfilt(b, a, v)  # zero phase
    return np.clip(v, bounds[0], bounds[1])


def _ahead(e: np.ndarray, lead: int, periodic: bool) -> np.ndarray:
    """The error ``lead`` steps later (wrapped around a period, or holding the last value)."""
    if not lead:
        return e
    return np.roll(e, -lead) if periodic else np.concatenate([e[lead:], np.full(lead, e[-1])])


def fingerprint(*parts: Any) -> str:
    """A stable hash of JSON-able values (configs as dicts, settings, arrays as lists)."""
    h = hashlib.sha1()
    for p in parts:
        h.update(json.dumps(p, sort_keys=True, default=_jsonable).encode())
    return h.hexdigest()[:24]


def _jsonable(v: Any) -> Any:
    if isinstance(v, np.ndarray):
        return v.tolist()
    if hasattr(v, "model_dump"):
        return v.model_dump()
    return str(v)


def cached(kind: str, key: str, compute: Callable[[], dict[str, np.ndarray]]) -> dict[str, np.ndarray]:
    """``compute()`` once per key on this machine (``~/.cache/rehab-hil/<kind>/<key>.npz``); a
    damaged cache file is recomputed, never trusted."""
    d: Path = cache_dir().parent / kind
    path = d / f"{key}.npz"
    if path.exists():
        try:
            with np.load(path) as z:
                return {k: z[k] for k in z.files}
        except (OSError, ValueError, KeyError):
            pass
    out = compute()
    d.mkdir(parents=True, exist_ok=True)
    tmp = path.with_suffix(f".{os.getpid()}.tmp.npz")
    np.savez(tmp, **out)
    os.replace(tmp, path)  # atomic: parallel workers never read half a file
    return out
