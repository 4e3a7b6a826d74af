"""Movement smoothness of a speed profile: SPARC and the log dimensionless jerk.

SPARC, the spectral arc length (Balasubramanian et al., IEEE TBME 59(8), 2012; JNER 12:112, 2015):
the length of the normalised Fourier magnitude spectrum of the speed, over frequencies up to the
last one whose magnitude stays above ``amp_th`` (at most ``fc``), with frequency scaled to that band:
a smooth movement has a short, simple spectrum (closer to zero); corrections add arcs (more negative).
The log dimensionless jerk: -ln(T^3 / v_peak^2 x integral of (d^2 v / dt^2)^2 dt), from the same
speed profile (Balasubramanian et al. 2015). Defaults as the authors' reference implementation
(padlevel 4, fc 10 Hz, amp_th 0.05); its published example values pin both here (tests).
"""

from __future__ import annotations

import math

import numpy as np

__all__ = ["log_dimensionless_jerk", "sparc"]


def sparc(speed: np.ndarray, fs_hz: float, padlevel: int = 4, fc_hz: float = 10.0, amp_th: float = 0.05) -> float:
    """The spectral arc length of ``speed`` sampled at ``fs_hz`` (nan: too short or no motion)."""
    v = np.asarray(speed, float)
    if v.size < 2 or not np.any(v):
        return math.nan
    n_fft = 2 ** (math.ceil(math.log2(v.size)) + padlevel)
    mag = np.abs(np.fft.rfft(v, n_fft))
    mag /= mag.max()
    freq = np.arange(mag.size) * fs_hz / n_fft
    band = freq <= fc_hz
    freq, mag = freq[band], mag[band]
    above = np.flatnonzero(mag >= amp_th)
    lo, hi = above[0], above[-1] + 1
    freq, mag = freq[lo:hi], mag[lo:hi]
    if freq.size < 2:
        return 0.0
    df = np.diff(freq) / (freq[-1] - freq[0])
    return float(-np.sum(np.hypot(df, np.diff(mag))))


def log_dimensionless_jerk(speed: np.ndarray, fs_hz: float) -> float:
    """-ln |dimensionless jerk| of ``speed`` sampled at ``fs_hz`` (nan: too short or no motion)."""
    v = np.asarray(speed, float)
    peak = float(np.max(np.abs(v))) if v.size else 0.0
    if v.size < 3 or peak == 0.0:
        return math.nan
    dt = 1.0 / fs_hz
    jerk = np.diff(v, 2) / dt**2
    duration = v.size * dt
    if peak**2 == 0.0:  # a speed so small that its square underflows: no motion to judge
        return math.nan
    dimensionless = duration**3 / peak**2 * float(np.sum(jerk**2)) * dt
    return -math.log(dimensionless) if 0 < dimensionless < math.inf else math.nan
