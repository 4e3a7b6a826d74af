"""Where the residual concentrates (time windows, state regions) and what it looks like.

Regions are defined on the measured primary channel (the plant's first output: an angle or a
temperature) and its smoothed rate: reversals of motion, fast motion, rest, high displacement
(or high temperature), rising vs falling (heating vs cooling for a temperature), and high force
when a force channel is present
(channel kinds come from the plant's measured ports). Signatures per channel: lag (cross-correlation of the rates),
offset (mean residual), gain error (slope of measured on model minus one), dead zone (residual
at reversals relative to elsewhere, the mark of backlash and stiction).
"""

from __future__ import annotations

import itertools
from collections.abc import Mapping, Sequence

import numpy as np
from scipy.signal import savgol_filter

__all__ = ["delay_seeds", "regions", "signatures", "time_windows"]

N_WINDOWS = 10
REVERSAL_S = 0.15  # half-width of the window around a reversal of motion


def _rate(t: np.ndarray, y: np.ndarray) -> np.ndarray:
    dt = float(np.median(np.diff(t)))
    win = min(max(5, round(0.05 / dt) | 1), len(y) if len(y) % 2 else len(y) - 1)
    ys = savgol_filter(y, win, 2) if win > 3 else y
    return np.gradient(ys, t)


def _rms(r: np.ndarray) -> float:
    return float(np.sqrt(np.mean(r**2))) if r.size else float("nan")


def time_windows(t: np.ndarray, r: np.ndarray, n: int = N_WINDOWS) -> list[dict[str, float]]:
    """RMS of the combined scaled residual ``r`` (samples) in ``n`` equal time windows."""
    edges = np.linspace(t[0], t[-1], n + 1)
    total = _rms(r)
    out = []
    for a, b in itertools.pairwise(edges):
        m = (t >= a) & (t <= b)
        out.append({"start_s": float(a), "end_s": float(b), "rms": _rms(r[m]),
                    "ratio": _rms(r[m]) / total if total > 0 else float("nan")})
    return out


def _masks(t: np.ndarray, measured: Mapping[str, np.ndarray], primary: str,
           kinds: Mapping[str, str]) -> dict[str, np.ndarray]:
    y = measured[primary]
    v = _rate(t, y)
    vmax = float(np.max(np.abs(v))) or 1.0
    moving = np.abs(v) > 0.05 * vmax
    thermal = kinds.get(primary) == "temperature"
    masks: dict[str, np.ndarray] = {}
    sign = np.sign(v) * moving
    nz = np.nonzero(sign)[0]
    rev = np.zeros(t.size, bool)
    if nz.size > 1:
        flips = nz[1:][sign[nz[1:]] != sign[nz[:-1]]]
        for i in flips:
            rev |= np.abs(t - t[i]) <= REVERSAL_S
    masks["reversal" if not thermal else "heating_cooling_switch"] = rev
    masks["rising" if not thermal else "heating"] = v > 0.05 * vmax
    masks["falling" if not thermal else "cooling"] = v < -0.05 * vmax
    masks["fast_motion" if not thermal else "fast_change"] = np.abs(v) > np.quantile(np.abs(v), 0.75)
    masks["rest"] = ~moving
    masks["high_displacement" if not thermal else "high_temperature"] = y > np.quantile(y, 0.75)
    for name, sig in measured.items():
        if kinds.get(name) == "force":
            masks[f"high_force ({name})"] = np.abs(sig) > np.quantile(np.abs(sig), 0.75)
    return masks


def regions(t: np.ndarray, measured: Mapping[str, np.ndarray], residual: np.ndarray,
            channels: Sequence[str], kinds: Mapping[str, str]) -> list[dict[str, object]]:
    """RMS of the scaled residual (channels x samples) in each state region, overall and per channel.

    ``kinds`` says what each channel measures (the plant's measured ports: angle, force,
    temperature ...). ``ratio`` > 1 means the residual concentrates there."""
    combined = np.sqrt(np.mean(residual**2, axis=0))
    total = _rms(combined)
    out = []
    for name, m in _masks(t, measured, channels[0], kinds).items():
        share = float(np.mean(m))
        rms = _rms(combined[m])
        out.append({
            "region": name, "share_of_time": share, "rms": rms,
            "ratio": rms / total if total > 0 and m.any() else float("nan"),
            "per_channel_rms": {c: _rms(residual[i][m]) for i, c in enumerate(channels)},
        })
    return out


def signatures(t: np.ndarray, measured: Mapping[str, np.ndarray], model: Mapping[str, np.ndarray],
               channels: Sequence[str], kinds: Mapping[str, str]) -> dict[str, dict[str, float]]:
    """Per channel: lag [s] (measured behind model > 0), offset and gain error, dead-zone ratio."""
    dt = float(np.median(np.diff(t)))
    masks = _masks(t, measured, channels[0], kinds)
    rev = masks.get("reversal", masks.get("heating_cooling_switch"))
    out = {}
    for c in channels:
        m, y = measured[c], model[c]
        r = y - m
        a = _rate(t, m)
        b = _rate(t, y)
        a, b = a - a.mean(), b - b.mean()
        max_lag = min(round(0.2 / dt), len(a) // 4)
        lags = np.arange(-max_lag, max_lag + 1)
        xc = [float(a[max(0, k):len(a) + min(0, k)] @ b[max(0, -k):len(b) - max(0, k)]) for k in lags]
        lag = float(lags[int(np.argmax(xc))] * dt)
        A = np.column_stack([y, np.ones_like(y)])
        (gain, _), *_ = np.linalg.lstsq(A, m, rcond=None)
        inside, outside = _rms(r[rev]), _rms(r[~rev])
        out[c] = {
            "lag_s": lag,
            "offset": float(np.mean(r)),
            "gain_error": float(gain - 1.0) if np.ptp(y) > 0 else float("nan"),
            "dead_zone_ratio": inside / outside if rev.any() and (~rev).any() and outside > 0 else float("nan"),
        }
    return out


def delay_seeds(t: np.ndarray, measured: Mapping[str, np.ndarray], model: Mapping[str, np.ndarray],
                channels: Sequence[str], kinds: Mapping[str, str]) -> dict[str, list[float]]:
    """Extra start values for a delay's fit (``fitting.regression_start``): the first channel's lag
    behind the model, when the measurement lags at all."""
    lag = signatures(t, measured, model, channels[:1], kinds)[channels[0]]
    return {"delay_s": [lag["lag_s"]]} if lag["lag_s"] > 0 else {}
