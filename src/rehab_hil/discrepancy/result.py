"""What the discrepancy workflow found: candidates per round, the chosen terms (effects and nominal
parameters), near-aliases, an unexplained residual, the start state and the replay mode; written
out by ``report.py``."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from rehab_hil.discrepancy.fitting import Fit
from rehab_hil.discrepancy.initial_state import InitialState
from rehab_hil.discrepancy.replay import channel_metrics
from rehab_hil.discrepancy.selection import Score

__all__ = ["Alias", "Candidate", "Result", "Round", "effect_phrase", "parameter_sentence"]

Z95 = 1.96


@dataclass
class Candidate:
    fit: Fit
    score: Score
    delta_bic: float  # versus the model of this round (negative: better)
    improvement: float  # largest relative cut of a channel's held-out RMS error
    significant: bool
    sim: dict[str, np.ndarray] | None = field(default=None, repr=False)  # full-record outputs

    @property
    def kind(self) -> str:
        """"effect" or "parameter"."""
        return self.fit.kind


@dataclass
class Round:
    baseline: Score
    candidates: list[Candidate]  # best first
    chosen: str | None


@dataclass
class Alias:
    """Two candidates this record cannot tell apart, and the experiment that would."""

    round: int
    chosen: str
    other: str
    delta_bic: float
    experiment: str
    split: bool = False  # the fit part preferred ``other``, the held-out part ``chosen``

    def sentence(self) -> str:
        why = ("the fit part prefers " + self.other if self.split
               else "held-out scores within the alias margin") + f", delta BIC {self.delta_bic:+.1f}"
        return (f"{self.chosen} and {self.other} explain the residual about equally ({why}): not distinguishable "
                f"from this record; to tell them apart: {self.experiment}")


def effect_phrase(fit: Fit, unit: str = "N m") -> str:
    """An effect as the conclusion names it: a direction-dependent friction by its level each way
    ("coulomb_friction_directional (friction 0.030 N m turning +, 0.012 N m turning -)"), others by name."""
    p = fit.params
    if fit.effect == "coulomb_friction_directional":
        return (f"{fit.effect} (friction {p['level_pos_nm']:.3g} {unit} turning +, {p['level_neg_nm']:.3g} {unit} "
                "turning -)")
    if fit.effect == "viscous_friction_directional":
        return (f"{fit.effect} (damping {p['damping_pos_nm_s_per_rad']:.3g} {unit} s per unit turning +, "
                f"{p['damping_neg_nm_s_per_rad']:.3g} turning -)")
    return fit.effect


def parameter_sentence(fit: Fit, inseparable: bool = False) -> str:
    """'parameter X is off by N % (95 % CI a .. b %)'; no interval for a parameter the record cannot
    separate from another (``identify``): its own interval would be a wrong story told with confidence."""
    e, se = fit.params["error_fraction"], fit.stderr.get("error_fraction", float("nan"))
    if inseparable:
        return f"parameter {fit.effect} is off by {100 * e:+.1f} % (not separable: see below)"
    ci = (f"95 % CI {100 * (e - Z95 * se):+.1f} .. {100 * (e + Z95 * se):+.1f} %" if np.isfinite(se)
          else "CI not available")
    return f"parameter {fit.effect} is off by {100 * e:+.1f} % ({ci})"


@dataclass
class Result:
    plant: str
    channels: list[str]
    kinds: dict[str, str]  # channel -> what it measures (angle, force, temperature ...)
    t: np.ndarray
    measured: dict[str, np.ndarray]
    nominal: dict[str, np.ndarray]
    augmented: dict[str, np.ndarray]
    chosen: list[Fit]  # effects and nominal parameters, after the last joint refit
    rounds: list[Round]
    split_s: float
    scale: dict[str, float]
    wall_s: float = 0.0
    extras: dict[str, Any] = field(default_factory=dict)
    initial_state: InitialState | None = None
    mode: str = "open"
    drift: dict[str, float] = field(default_factory=dict)  # open-loop and shooting RMS of the nominal
    aliases: list[Alias] = field(default_factory=list)
    unexplained: dict[str, dict[str, float]] = field(default_factory=dict)  # channel -> rms, floor, ...
    unexplained_where: dict[str, Any] = field(default_factory=dict)
    validation: Any = None  # validation.Validation: scored on a second record (--validate)
    joint: Any = None  # identify.JointIdentification: every nominal parameter fitted together
    # {"measure": how, "records": [{"data", "nominal", "augmented"} per-channel metrics]}: the gap per
    # record in one measure (``records.GAP_MEASURE``), the same as a validation record's
    gaps: dict[str, Any] = field(default_factory=dict)
    bounds: list[str] = field(default_factory=list)  # sentences: a fitted value that ended on its bound
    lacking: list[str] = field(default_factory=list)  # experiments the records lack (``experiments``)
    dropped: list[str] = field(default_factory=list)  # terms of the best set that did not pay for themselves

    @property
    def named(self) -> list[str]:
        """Library effects chosen (parameters are not effects)."""
        return [f.effect for f in self.chosen if f.kind == "effect"]

    @property
    def parameters(self) -> list[Fit]:
        return [f for f in self.chosen if f.kind == "parameter"]

    @property
    def conclusion(self) -> str:
        """One line: effects, parameters off, near-aliases, an unexplained residual, or a fit."""
        parts = []
        if self.named:
            unit = "N" if "position" in self.kinds.values() else "N m"
            phrases = [effect_phrase(f, unit) for f in self.chosen if f.kind == "effect"]
            parts.append(f"missing effect found: {', '.join(phrases)}")
        mixed = {m for g in (self.joint.inseparable if self.joint is not None else []) for m in g}
        on_bound = {b.split(" ended on")[0] for b in self.bounds}
        parts += [parameter_sentence(f, f.effect in mixed) for f in self.parameters if f.effect not in on_bound]
        parts += self.bounds
        parts += [a.sentence() for a in self.aliases]
        chosen = {f.effect for f in self.chosen}
        if self.joint is not None:  # a chosen term the record cannot separate from another: said so
            parts += [s for g, s in zip(self.joint.inseparable, self.joint.sentences(), strict=True)
                      if any(m.split(".")[0] in chosen or m in chosen for m in g)]
        if self.unexplained:
            where = self.unexplained_where
            chans = ", ".join(self.unexplained)
            loc = (f" (largest in {where['region']} and at {where['window_start_s']:.1f}-{where['window_end_s']:.1f} s)"
                   if where else "")
            parts.append(("unexplained residual" if not self.chosen else "unexplained residual remains")
                         + f" on {chans}{loc}")
        if not parts:
            parts.append("no missing effect found: the model fits within the noise")
        return "; ".join(parts)

    def metrics(self, which: str, part: str = "all") -> dict[str, dict[str, float]]:
        """Per-channel RMSE/MAE/max error of the nominal or augmented model (all or held-out)."""
        model = self.nominal if which == "nominal" else self.augmented
        m = self.t >= self.split_s if part == "holdout" else np.ones(self.t.size, bool)
        return {c: channel_metrics(self.measured[c][m], model[c][m]) for c in self.channels}
