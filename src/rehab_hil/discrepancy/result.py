"""What the discrepancy workflow found: candidates per round, the chosen effects, the model outputs
before and after; written out by ``report.py``."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from rehab_hil.discrepancy.fitting import Fit
from rehab_hil.discrepancy.replay import channel_metrics
from rehab_hil.discrepancy.selection import Score

__all__ = ["Candidate", "Result", "Round"]


@dataclass
class Candidate:
    fit: Fit
    score: Score
    delta_bic: float  # versus the model of this round (negative: better)
    improvement: float  # largest relative cut of a channel's held-out RMS error
    significant: bool
    sim: dict[str, np.ndarray] | None = field(default=None, repr=False)  # full-record outputs


@dataclass
class Round:
    baseline: Score
    candidates: list[Candidate]  # best first
    chosen: str | None


@dataclass
class Result:
    plant: str
    channels: list[str]
    kinds: dict[str, str]  # channel -> what it measures (angle, force, temperature ...)
    t: np.ndarray
    measured: dict[str, np.ndarray]
    nominal: dict[str, np.ndarray]
    augmented: dict[str, np.ndarray]
    chosen: list[Fit]
    rounds: list[Round]
    split_s: float
    scale: dict[str, float]
    wall_s: float = 0.0
    extras: dict[str, Any] = field(default_factory=dict)

    @property
    def named(self) -> list[str]:
        return [f.effect for f in self.chosen]

    def metrics(self, which: str, part: str = "all") -> dict[str, dict[str, float]]:
        """Per-channel RMSE/MAE/max error of the nominal or augmented model (all or held-out)."""
        model = self.nominal if which == "nominal" else self.augmented
        m = self.t >= self.split_s if part == "holdout" else np.ones(self.t.size, bool)
        return {c: channel_metrics(self.measured[c][m], model[c][m]) for c in self.channels}
