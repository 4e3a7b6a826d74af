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
from rehab_hil.discrepancy.shooting import SEGMENT_S
from rehab_hil.discrepancy.verdict import ALIAS_DELTA_BIC, ALIAS_RMS_SHARE, channel_unit, residual_stats

__all__ = ["Alias", "Candidate", "Result", "Round", "direction_sentence", "effect_phrase", "parameter_sentence"]

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
        """Why the two go together, in the words their scores allow: "about equally" only when their
        held-out BIC lie within the alias margin; the record's halves disagreeing, or a close error on
        one channel under a clearly better BIC, are said as such."""
        d = f"delta BIC {self.delta_bic:+.1f}"
        if self.split:
            why = (f"{self.chosen} and {self.other} are told apart differently by the two parts of the record "
                   f"(the fit part prefers {self.other}, the held-out part {self.chosen}, {d})")
        elif abs(self.delta_bic) < ALIAS_DELTA_BIC:
            why = f"{self.chosen} and {self.other} explain the residual about equally (held-out scores, {d})"
        else:
            why = (f"{self.chosen} scores clearly better than {self.other} ({d}), but {self.other} comes within "
                   f"{100 * ALIAS_RMS_SHARE:.0f} % of its held-out error on the channel it cuts most")
        return f"{why}: not distinguishable from this record; to tell them apart: {self.experiment}"

    @property
    def pair(self) -> frozenset[str]:
        return frozenset((self.chosen, self.other))


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


def direction_sentence(chosen: list[Fit], unit: str = "N m") -> str | None:
    """Coulomb friction named beside a constant load is a friction that differs with the direction
    (EMPS eq 1: Fc sgn(q') + offset): its level against each direction of motion, or None."""
    fits = {f.effect: f.params for f in chosen if f.kind == "effect"}
    if "coulomb_friction" not in fits or "constant_load" not in fits:
        return None
    fc, load = fits["coulomb_friction"]["level_nm"], fits["constant_load"]["level_nm"]  # load: -level on the axis
    return (f"together a friction that depends on the direction: {fc + load:.3g} {unit} against moving +, "
            f"{fc - load:.3g} {unit} against moving - (Coulomb {fc:.3g} {unit} and a constant load of "
            f"{load:.3g} {unit})")


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
    judgement: Any = None  # judge.Judgement: the chosen terms judged on held-out data, what they rejected

    @property
    def rejected(self) -> list[Any]:
        """The chosen terms the held-out data rejected (``judge.Rejection``): not findings."""
        return list(self.judgement.rejected) if self.judgement is not None else []

    @property
    def named(self) -> list[str]:
        """Library effects chosen (parameters are not effects)."""
        return [f.effect for f in self.chosen if f.kind == "effect"]

    @property
    def parameters(self) -> list[Fit]:
        return [f for f in self.chosen if f.kind == "parameter"]

    @property
    def conclusion(self) -> str:
        """One line: effects, parameters off, what the held-out data rejected (with the figures; the
        given value kept), near-aliases (each pair once), an unexplained residual with its size beside
        the noise floor and the spread, or a fit within the noise (with both figures)."""
        parts = []
        if self.named:
            unit = "N" if "position" in self.kinds.values() else "N m"
            phrases = [effect_phrase(f, unit) for f in self.chosen if f.kind == "effect"]
            parts.append(f"missing effect found: {', '.join(phrases)}")
            parts += [d] if (d := direction_sentence(self.chosen, unit)) else []
        mixed = {m for g in (self.joint.inseparable if self.joint is not None else []) for m in g}
        on_bound = {b.split(" ended on")[0] for b in self.bounds}
        parts += [parameter_sentence(f, f.effect in mixed) for f in self.parameters if f.effect not in on_bound]
        parts += self.bounds
        parts += [self.judgement.summary(), *(r.sentence() for r in self.rejected)] if self.rejected else []
        seen: set[frozenset[str]] = set()
        for a in self.aliases:  # a pair met again in a later round is said once
            if a.pair not in seen:
                seen.add(a.pair)
                parts.append(a.sentence())
        chosen = {f.effect for f in self.chosen}
        if self.joint is not None:  # a chosen term the record cannot separate from another: said so
            parts += [s for g, s in zip(self.joint.inseparable, self.joint.sentences(), strict=True)
                      if any(m.split(".")[0] in chosen or m in chosen for m in g)]
        rejections = {r.sentence() for r in self.rejected}  # a rejection is no finding: "no missing effect" stays
        rejections |= {self.judgement.summary()} if self.rejected else set()
        parts += self._residual_sentences(any(p not in rejections for p in parts))
        return "; ".join(dict.fromkeys(parts))

    def residuals(self) -> dict[str, dict[str, float | bool]]:
        """Per channel, the final model's held-out residual beside the data's noise floor and spread
        (``verdict.residual_stats``)."""
        m = self.t >= self.split_s
        if not np.any(m):
            m = np.ones(self.t.size, bool)
        return {c: residual_stats(self.measured[c], float(np.sqrt(np.mean((self.augmented[c][m]
                                                                           - self.measured[c][m]) ** 2))))
                for c in self.channels}

    def _residual_sentences(self, found: bool) -> list[str]:
        """The residual's part of the conclusion: unexplained (with its size, its share of the spread and
        the noise floor), above the noise but small, or within the noise (both figures printed)."""
        stats = self.residuals()

        def figures(c: str) -> str:
            s, u = stats[c], channel_unit(c)
            return (f"{c} ({s['rms']:.2g} {u} RMS, {100 * float(s['share_of_spread']):.2g} % of its spread; noise "
                    f"floor {s['noise_floor']:.2g} {u})").replace("  ", " ").replace(" )", ")")

        if self.unexplained:
            where = self.unexplained_where
            loc = (f" (largest in {where['region']} and at {where['window_start_s']:.1f}-{where['window_end_s']:.1f} s)"
                   if where else "")
            head = "unexplained residual" if not self.chosen else "unexplained residual remains"
            return [f"{head} on {', '.join(figures(c) for c in self.unexplained if c in stats)}{loc}"]
        above = [c for c in self.channels if not stats[c]["at_noise"]]
        if above:
            lead = "" if found else "no missing effect found; "
            return [f"{lead}a residual above the noise floor remains (not a fit within the noise) on "
                    + ", ".join(figures(c) for c in above)]
        if found:
            return []
        return ["no missing effect found: the model fits within the noise ("
                + "; ".join(f"{c} residual {stats[c]['rms']:.2g} {channel_unit(c)}, noise floor "
                            f"{stats[c]['noise_floor']:.2g} {channel_unit(c)}" for c in self.channels) + ")"]

    @property
    def measure(self) -> str:
        """What the RMSE of ``metrics`` measures: the replay mode the models were run in."""
        if self.mode == "shooting":
            return f"multiple shooting: {SEGMENT_S:g} s segments re-anchored on the measured state"
        return "whole-record open-loop replay from the estimated start"

    def metrics(self, which: str, part: str = "all") -> dict[str, dict[str, float]]:
        """Per-channel RMSE/MAE/max error of the nominal or augmented model (all or held-out)."""
        model = self.nominal if which == "nominal" else self.augmented
        m = self.t >= self.split_s if part == "holdout" else np.ones(self.t.size, bool)
        return {c: channel_metrics(self.measured[c][m], model[c][m]) for c in self.channels}
