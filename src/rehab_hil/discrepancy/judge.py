"""Held-out data judge the findings (issue 47 item 4): a term that makes them worse is not a finding.

The search chooses terms on the fit part and its held-out score; on records it never saw, a
correction can still make the model worse than the one the user gave (a servo's reference model,
already holding Coulomb friction and its asymmetry, came back with inertia +68 %, viscous +31 % and
Coulomb -23 % while two validation records' velocity RMSE went 19.1 -> 34.6 rad/s). So every chosen
term is judged on held-out data before it is reported:

- **where**: the validation records when there are any (each replayed whole from its own start
  state estimated under the model judged, never re-anchored, as ``validation`` scores them), else
  the fit records' own held-out parts (the workflow's split; each record from its start state
  estimated on its fit part under the model judged, in its replay mode);
- **measure**: the RMS of the scaled residual, each channel weighed as the fits weigh it
  (``Replay.fit_weight``), pooled over every held-out sample; per channel RMSE in its unit for the
  sentences;
- **rule** (``judge``, backward elimination, nothing to tune): while some chosen term, set back to its
  given value (a declared parameter to the config's, an effect off), leaves a lower held-out error
  than with it, the term whose removal lowers it most is rejected and the rest are refitted on the
  fit parts without it (a term the refit leaves a rounding of "off", by ``significance.relevant``,
  goes too, as the search prunes it); if what is left still scores worse than the model as given, it
  is rejected as a whole. A rejected term is not a finding: the conclusion says the held-out data
  rejected it, with the figures, and its given value stays (``augmented.toml`` too).

Without validation records the held-out parts rarely reject anything (the search already asked each
term to cut their error); they differ where the records do (a KUKA joint's record C supports a
constant load that records A and B reject, ``tests/discrepancy/test_real_kuka.py``).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from rehab_hil.discrepancy.fitting import Fit, Term, fit_joint
from rehab_hil.discrepancy.initial_state import estimate_initial_state
from rehab_hil.discrepancy.records import from_own_start
from rehab_hil.discrepancy.selection import bounded
from rehab_hil.discrepancy.significance import relevant, score
from rehab_hil.discrepancy.validation import validation_replay
from rehab_hil.discrepancy.verdict import channel_unit
from rehab_hil.discrepancy.wording import change_words, is_linear, param_label, param_unit

__all__ = ["PARTS", "VALIDATION", "HeldOut", "HeldOutError", "Judgement", "Rejection", "applied", "cut_pct",
           "finding_phrase", "judge", "judge_findings"]

VALIDATION = "the validation records"
PARTS = "the records' held-out parts"


@dataclass(frozen=True)
class HeldOutError:
    """A model's error on the held-out data: the decision measure and each channel's RMSE."""

    combined: float  # RMS of the weighted scaled residual over every held-out sample
    rmse: dict[str, float]  # per channel, pooled over the held-out records, in the channel's unit

    def as_dict(self) -> dict[str, Any]:
        return {"combined": self.combined, "rmse": self.rmse}


@dataclass(frozen=True)
class Piece:
    """One held-out record: its replay, the samples its start state is estimated on, the first
    sample scored, and the replay mode (``"open"``: a whole record, never re-anchored)."""

    replay: Any
    n_fit: int
    first: int
    mode: str | None


@dataclass
class HeldOut:
    """The held-out data a parameter vector is judged on (module docstring): ``pieces`` scored with
    the fit's channel ``scale`` and ``weight``; ``what`` says which data in the conclusion."""

    what: str
    pieces: list[Piece]
    channels: list[str]
    scale: np.ndarray
    weight: np.ndarray
    names: list[str] = field(default_factory=list)  # the records, as the report names them

    @classmethod
    def parts(cls, fitted: Any, n_trains: Sequence[int]) -> HeldOut:
        """The held-out parts of the fit records (a ``Replay`` or a ``RecordSet``'s replays)."""
        replays = list(getattr(fitted, "replays", [fitted]))
        pieces = [Piece(r, n, n, None) for r, n in zip(replays, n_trains, strict=True) if n < r.t.size]
        return cls(PARTS, pieces, list(fitted.channels), np.asarray(fitted.scale, float),
                   np.asarray(fitted.fit_weight, float), [str(n) for n in getattr(fitted, "names", [])])

    @classmethod
    def validation(cls, fitted: Any, replays: Sequence[Any], names: Sequence[str | Path]) -> HeldOut:
        """Validation records, each scored whole (``validation.validation_replay`` builds them)."""
        return cls(VALIDATION, [Piece(r, r.t.size, 0, "open") for r in replays], list(fitted.channels),
                   np.asarray(fitted.scale, float), np.asarray(fitted.fit_weight, float), [str(n) for n in names])

    def error(self, P: np.ndarray) -> HeldOutError:
        """The held-out error of the model with parameter vector ``P`` (each record's start state
        under ``P``; the replays' own start states are left as they were)."""
        sq, count = np.zeros(len(self.channels)), 0
        sq_units = np.zeros(len(self.channels))
        for p in self.pieces:
            sim = from_own_start(p.replay, P, p.n_fit, p.mode)
            err = np.vstack([sim[c][p.first:] - p.replay.measured[c][p.first:] for c in self.channels])
            scaled = bounded(err / self.scale[:, None]) * self.weight[:, None]
            sq += np.sum(scaled**2, axis=1)
            sq_units += np.sum(np.where(np.isfinite(err), err, np.inf) ** 2, axis=1)
            count += err.shape[1]
        n = max(count, 1)
        return HeldOutError(float(np.sqrt(np.sum(sq) / (n * len(self.channels)))),
                            {c: float(np.sqrt(s / n)) for c, s in zip(self.channels, sq_units, strict=True)})


@dataclass(frozen=True)
class Rejection:
    """Chosen terms the held-out data rejected: with them (``with_terms``) the held-out error is
    higher than with their given values (``without``: the same terms but this one as they were
    fitted; the model as given when ``together``)."""

    terms: tuple[str, ...]
    findings: tuple[str, ...]  # each as the conclusion would have named it ("load.inertia_kg_m2 off by +68.0 %")
    kinds: tuple[str, ...]  # "effect" or "parameter", per term
    where: str
    with_terms: HeldOutError
    without: HeldOutError
    together: bool = False  # what was left scored worse than the model as given, as a whole

    def sentence(self) -> str:
        """'the validation records rejected load.inertia_kg_m2 off by +68.0 %: their error is higher with it
        than with its given value (velocity_rad_s RMSE 19.1 -> 34.6 rad/s, worse by 81.2 %); the given
        value is kept'."""
        figures = "; ".join(
            f"{c} RMSE {self.without.rmse[c]:.3g} -> {self.with_terms.rmse[c]:.3g} {channel_unit(c)}".rstrip()
            + f", {change_words(cut_pct(self.without.rmse[c], self.with_terms.rmse[c]))}" for c in self.without.rmse)
        if self.together:
            against, keep = "the model as given", "the model as given is kept"
        elif self.kinds[0] == "parameter":
            against, keep = "its given value", "the given value is kept"
        else:
            against, keep = "without it", "it is not added"
        them = "them" if len(self.terms) > 1 else "it"
        return (f"{self.where} rejected {' and '.join(self.findings)}{' together' if self.together else ''}: "
                f"their error is higher with {them} than {'with ' if against != 'without it' else ''}{against} "
                f"({figures}); {keep}")

    def as_dict(self) -> dict[str, Any]:
        return {"terms": list(self.terms), "findings": list(self.findings), "on": self.where,
                "together": self.together, "with": self.with_terms.as_dict(), "without": self.without.as_dict(),
                "sentence": self.sentence()}


@dataclass
class Judgement:
    """What the held-out data kept: the terms and their fits (refitted without the rejected ones), the
    resulting parameter vector, the rejections, and the held-out error of the model as given and of
    the final one."""

    terms: list[Term]
    fits: list[Fit]
    P: np.ndarray
    rejected: list[Rejection]
    given: HeldOutError  # the model as given
    found: HeldOutError  # the terms as the search found them
    final: HeldOutError  # what was kept
    where: str
    names: list[str] = field(default_factory=list)  # the held-out records

    def summary(self) -> str:
        """The held-out error of the three models, per channel: 'judged on the validation records:
        velocity_rad_s RMSE 21.1 rad/s with the model as given, 30.5 with the terms as found (worse by
        44.8 %), 21.1 with what was kept (unchanged)'."""
        def one(c: str) -> str:
            g, f, k = self.given.rmse[c], self.found.rmse[c], self.final.rmse[c]
            return (f"{c} RMSE {g:.3g} {channel_unit(c)} with the model as given, {f:.3g} with the terms as found "
                    f"({change_words(cut_pct(g, f))}), {k:.3g} with what was kept ({change_words(cut_pct(g, k))})"
                    ).replace("  ", " ")
        return f"judged on {self.where}: " + "; ".join(one(c) for c in self.given.rmse)

    def as_dict(self) -> dict[str, Any]:
        return {"on": self.where, "records": self.names, "given": self.given.as_dict(), "found": self.found.as_dict(),
                "final": self.final.as_dict(), "summary": self.summary(),
                "rejected": [r.as_dict() for r in self.rejected]}


Refit = Callable[[list[Term], list[Fit]], tuple[list[Term], list[Fit]]]


def applied(P0: np.ndarray, terms: Sequence[Term], fits: Sequence[Fit]) -> np.ndarray:
    """``P0`` with every term at its fitted values."""
    P = P0
    for t, f in zip(terms, fits, strict=True):
        P = t.apply(P, f.params)
    return P


def judge(P0: np.ndarray, terms: Sequence[Term], fits: Sequence[Fit], held: HeldOut, refit: Refit,
          finding: Callable[[Fit], str]) -> Judgement:
    """The rule of the module docstring on the chosen ``terms`` (fitted as ``fits``): ``refit`` fits a
    smaller set again on the fit parts, ``finding`` words a fit as the conclusion would name it."""
    terms, fits = list(terms), list(fits)
    given = held.error(P0)
    now = found = held.error(applied(P0, terms, fits)) if terms else given
    rejected: list[Rejection] = []
    while terms:
        without = [given] if len(terms) == 1 else [
            held.error(applied(P0, terms[:i] + terms[i + 1:], fits[:i] + fits[i + 1:])) for i in range(len(terms))]
        i = int(np.argmin([w.combined for w in without]))
        if without[i].combined < now.combined:  # the term makes the held-out data worse: out, the rest refitted
            rejected.append(Rejection((terms[i].name,), (finding(fits[i]),), (terms[i].kind,), held.what, now,
                                      without[i]))
            terms, fits = refit(terms[:i] + terms[i + 1:], fits[:i] + fits[i + 1:]) if len(terms) > 1 else ([], [])
            now = held.error(applied(P0, terms, fits)) if terms else given
            continue
        if now.combined > given.combined:  # no single term to blame, but together worse than the model as given
            rejected.append(Rejection(tuple(t.name for t in terms), tuple(finding(f) for f in fits),
                                      tuple(t.kind for t in terms), held.what, now, given, together=True))
            terms, fits, now = [], [], given
        break
    return Judgement(terms, fits, applied(P0, terms, fits), rejected, given, found, now, held.what, held.names)


def judge_findings(fitted: Any, cfg: Any, P0: np.ndarray, terms: Sequence[Term], fits: Sequence[Fit],
                   n_trains: Sequence[int], validation: Sequence[tuple[Any, str | Path]], progress: Any) -> Judgement:
    """``judge`` the chosen terms of a search on ``fitted`` (a ``Replay`` or a ``RecordSet``, whose fit
    parts are the first ``n_trains`` samples of each record) on the ``validation`` records ((recording,
    path) pairs) or, without any, on the records' held-out parts; a smaller set is refitted from each
    record's start state under it. The fit records' start states are left under the last set fitted."""
    if validation:
        replays = [validation_replay(fitted, cfg, rec, path) for rec, path in validation]
        held = HeldOut.validation(fitted, replays, [p for _, p in validation])
    else:
        held = HeldOut.parts(fitted, n_trains)
    n_train = int(sum(n_trains))

    def refit(kept: list[Term], kept_fits: list[Fit]) -> tuple[list[Term], list[Fit]]:
        progress.start(f"refit of the terms {held.what} kept", None)
        P = applied(P0, kept, kept_fits)
        if hasattr(fitted, "estimate_starts"):  # several records: each its own start state
            fitted.estimate_starts(P)
        else:
            estimate_initial_state(fitted, P, n_train)
        new = fit_joint(fitted, P0, kept, [f.params for f in kept_fits], n_train, progress.advance)
        sim, hold = fitted.simulate(new[-1].P), slice(n_train, None)
        now = score(fitted, sim, hold, 0, 1.0)  # only its per-channel RMS is asked
        keep = [i for i, (t, f) in enumerate(zip(kept, new, strict=True)) if relevant(fitted, t, f, sim, hold, now)]
        terms, fits = [kept[i] for i in keep], [new[i] for i in keep]
        P = applied(P0, terms, fits)
        for f in fits:
            f.P = P
        return terms, fits

    progress.start(f"judging the chosen terms on {held.what}", None)
    linear = is_linear(fitted)
    return judge(P0, terms, fits, held, refit, lambda f: finding_phrase(f, linear))


def finding_phrase(fit: Fit, linear: bool = False) -> str:
    """A chosen term as the conclusion names it: "load.inertia_kg_m2 off by +68.0 %", or an effect
    with its values in the axis's units, "constant_load (level -65.5 N m)"."""
    if fit.kind == "parameter":
        return f"{fit.effect} off by {100 * fit.params['error_fraction']:+.1f} %"
    values = ", ".join(f"{param_label(k)} {v:.3g} {param_unit(k, linear)}".rstrip() for k, v in fit.params.items())
    return f"{fit.effect} ({values})"


def cut_pct(before: float, after: float) -> float:
    """The relative cut of an error, 100 (1 - after / before) in percent (negative: it rose)."""
    return 100.0 * (1.0 - after / before) if before > 0 else 0.0
