"""Score candidates on held-out data and decide whether any beats the current model.

The score is BIC on the held-out residual, n_eff ln(RSS / n) + k ln(n_eff), where n_eff counts
effectively independent samples: a model error is smooth, so neighbouring residuals are nearly
copies of each other, and n_eff = n (1 - rho) / (1 + rho) from the lag-1 autocorrelation rho of
the current model's held-out residual (AR(1) variance inflation). A candidate is chosen only if
its BIC is lower than the current model's by more than ``MIN_DELTA_BIC`` (very strong evidence on
the Kass-Raftery scale) AND it cuts the held-out RMS error of some channel by at least
``MIN_IMPROVEMENT`` and by more than ``RESOLUTION_FLOOR`` (per channel, so that sensor noise on
another channel cannot hide a real gain, and a statistically detectable but practically
negligible gain is not reported). Candidates are ranked significant first, then by BIC.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["BLOWUP", "MIN_DELTA_BIC", "MIN_IMPROVEMENT", "RESOLUTION_FLOOR", "Score", "bic", "bounded",
           "effective_fraction", "improvement", "is_significant"]

MIN_DELTA_BIC = 10.0
MIN_IMPROVEMENT = 0.15  # relative cut of a channel's held-out RMS error
# A cut of a channel's RMS error smaller than 0.5 % of its spread (its std) is below the resolution
# of the data (an encoder count is ~0.5 % of a typical motion): no evidence of a missing effect.
RESOLUTION_FLOOR = 0.005
BLOWUP = 1e3  # scaled residual that stands for a diverged simulation


def bounded(r: np.ndarray) -> np.ndarray:
    """A scaled residual with a diverged run's NaN and infinities as +-``BLOWUP``, and nothing beyond:
    a candidate that makes the model diverge is a very bad fit, not a crash."""
    return np.clip(np.nan_to_num(r, nan=BLOWUP, posinf=BLOWUP, neginf=-BLOWUP), -BLOWUP, BLOWUP)


def effective_fraction(residual: np.ndarray) -> float:
    """n_eff / n from the lag-1 autocorrelation of each channel's residual (rows), averaged."""
    r = np.atleast_2d(residual)
    fr = []
    for row in r:
        d = row - row.mean()
        den = float(d @ d)
        rho = float(d[1:] @ d[:-1]) / den if den > 0 else 0.0
        rho = min(max(rho, 0.0), 0.9999)
        fr.append((1.0 - rho) / (1.0 + rho))
    return float(np.clip(np.mean(fr), 1.0 / r.shape[1], 1.0))


@dataclass(frozen=True)
class Score:
    """Held-out figures of one model: RMS of the scaled residual, BIC, parameter count."""

    rms: float
    channel_rms: tuple[float, ...]
    bic: float
    n_params: int


def bic(residual: np.ndarray, n_params: int, fraction: float, weight: np.ndarray | None = None) -> Score:
    """BIC of a held-out scaled residual (channels x samples) with ``n_params`` fitted parameters;
    ``weight`` (per channel) weighs the channels in the BIC as the fits do (``Replay.fit_weight``),
    while the per-channel RMS stays in the scaled unit (the improvement and its floor)."""
    r = np.atleast_2d(residual)
    r = bounded(r)
    n = r.size
    rw = r if weight is None else r * np.asarray(weight, float)[:, None]
    rss = float(np.sum(rw**2))
    n_eff = max(n * fraction, n_params + 2.0)
    value = n_eff * np.log(max(rss, 1e-300) / n) + n_params * np.log(n_eff)
    per = tuple(float(np.sqrt(np.mean(row**2))) for row in r)
    return Score(float(np.sqrt(rss / n)), per, float(value), n_params)


def improvement(candidate: Score, current: Score) -> float:
    """Largest relative cut of a channel's held-out RMS error; a channel counts only if the cut
    itself exceeds the resolution floor (0 when none does)."""
    cuts = [1.0 - c / b for c, b in zip(candidate.channel_rms, current.channel_rms, strict=True)
            if b - c > RESOLUTION_FLOOR]
    return max(cuts, default=0.0)


def is_significant(candidate: Score, current: Score) -> bool:
    """Is the candidate significantly better than the current model (see module docstring)?"""
    return candidate.bic < current.bic - MIN_DELTA_BIC and improvement(candidate, current) >= MIN_IMPROVEMENT
