"""Effects chosen as a set: best-subset search over the library and the plant's parameters.

The greedy search (``workflow.Search``) names one term at a time, and a term named first keeps its
place even when a later set explains the data better without it (issue 38: on a servo's records a
viscous term 5x the catalogue was named first, and Coulomb friction, fitted on top of it, came out
at nothing). Here candidate *sets* are compared under one information criterion over all records:

1. Screen (``screen``): each term's regression start alone (``fitting.regression_start``: shape
   parameters on their grid, linear ones by regression) and the columns of its linear parameters,
   the fit-part residual's change per typical value of each, from the current model.
2. Rank (``rank_sets``): every set of up to ``MAX_TERMS`` terms by the BIC of its bounded linear
   least-squares fit to the residual (best-subset regression on the sensitivities; a sparse
   regression in the sense of Brunton, Proctor and Kutz 2016, exact where the library is small).
3. Refine: the best ``REFINE_SETS`` sets are fitted jointly (nonlinear, ``fitting.fit_joint``) over
   every record's fit part and scored on every record's held-out part (``selection.bic``).
4. Choose: the set of lowest held-out BIC; then every member must pay for itself: a member whose
   removal (the set without it, refitted) costs less than ``MIN_DELTA_BIC``, or that the fit left
   at "off" (``significance.relevant``), is dropped, and the smaller set is judged again. A set
   whose effect a declared parameter replaces within ``ALIAS_DELTA_BIC`` (a parameter whose sensitivity
   column lies in the effect's span, ``ALIKE``; others are not refitted) gives way to it
   (parameter before structure, ``verdict.tied_parameter``'s rule), and a refinement (a level per
   direction, ``Effect.refines``) that does not beat what it refines by ``MIN_DELTA_BIC`` gives way
   to the simpler effect. The final set must beat the
   nominal model (``selection.is_significant``); refined sets of the same size that differ from it
   in one term and score within the alias margin are its near-aliases.
"""

from __future__ import annotations

import itertools
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from scipy.optimize import lsq_linear

from rehab_hil.discrepancy.fitting import Fit, Objective, Term, fit_joint, regression_start
from rehab_hil.discrepancy.selection import MIN_DELTA_BIC, Score, effective_fraction, is_significant
from rehab_hil.discrepancy.significance import relevant, score
from rehab_hil.discrepancy.verdict import ALIAS_DELTA_BIC
from rehab_hil.effects import EFFECTS, nested

__all__ = ["MAX_TERMS", "REFINE_SETS", "Screened", "SetFit", "SetSearch"]

MAX_TERMS = 3  # the largest set compared
REFINE_SETS = 3  # sets fitted nonlinearly after the linear ranking
ALIKE = 0.9  # a parameter may stand for an effect when this share of its column lies in the effect's span
SHAPE_RANGE = (0.0, 1.5)  # a shape-only term's column (its best grid point) is scaled within this range


@dataclass
class Screened:
    """One term's screen: its start alone and its columns (fit-part residual change per typical
    value of each linear parameter; a shape-only term: the change at its best grid point)."""

    term: Term
    start: dict[str, float]
    columns: np.ndarray  # samples x k
    lower: np.ndarray  # coefficient bounds, in typical values (or shares of the grid point's change)
    upper: np.ndarray
    linear: list[str]  # parameter names of the columns ("" for a shape-only term)

    def values(self, z: np.ndarray) -> dict[str, float]:
        """The term's parameter values for column coefficients ``z``."""
        out = dict(self.start)
        if self.linear == [""]:
            return out  # a shape-only term starts at its best grid point
        for name, c in zip(self.linear, z, strict=True):
            p = next(q for q in self.term.params if q.name == name)
            out[name] = (p.off or 0.0) + float(c) * p.typical
        return out


@dataclass
class SetFit:
    """A set of terms fitted jointly: the fits, the parameter vector, the held-out score."""

    names: tuple[str, ...]
    fits: list[Fit]
    P: np.ndarray
    score: Score
    sim: dict[str, np.ndarray] = field(repr=False)


@dataclass
class SetSearch:
    """The set search on a replay or a ``records.RecordSet`` (module docstring)."""

    replay: Any  # a Replay or a RecordSet: simulate, residual, channels ...
    terms: list[Term]
    P0: np.ndarray
    n_train: int
    tick: Any = None  # called on every simulation
    seeds: Mapping[str, Sequence[float]] = field(default_factory=dict)
    max_terms: int = MAX_TERMS
    screened: dict[str, Screened] = field(default_factory=dict)
    ranked: list[tuple[tuple[str, ...], float]] = field(default_factory=list)  # (set, linear BIC), best first
    fitted: dict[frozenset[str], SetFit] = field(default_factory=dict)
    chosen: SetFit | None = None
    dropped: list[str] = field(default_factory=list)  # members of the best-scoring set the chosen one lacks
    swaps: list[tuple[str, str]] = field(default_factory=list)  # (effect, parameter named instead)

    @property
    def hold(self) -> slice:
        return slice(self.n_train, self.replay.t.size)

    def run(self) -> SetFit:
        """Screen, rank, refine and choose; returns the chosen set (empty: the nominal model)."""
        base = self.refit(())
        self.screen()
        self.rank_sets()
        for names, _ in self.ranked[:REFINE_SETS]:
            self.refit(names)
        top = min(self.fitted.values(), key=lambda s: s.score.bic)
        best = self._parameter_first(self._simpler_first(self._prune(top)))
        if best.names and not is_significant(best.score, base.score):
            best = base
        self.chosen = best
        self.dropped = [n for n in top.names if n not in best.names]
        return best

    # 1. screen ----------------------------------------------------------------------------------
    def screen(self) -> None:
        """Every term's start alone and its columns, from the nominal model."""
        obj = Objective(self.replay, self.n_train, self.tick)
        r0 = obj(self.P0)
        self._r0 = r0
        for term in self.terms:
            start = regression_start(term, lambda v, t=term: obj(t.apply(self.P0, v)), r0, self.seeds)
            lin = [p for p in term.params if p.linear]
            if lin:
                cols = [(obj(term.apply(self.P0, {**start, p.name: (p.off or 0.0) + p.typical})) - r0)
                        for p in lin]
                lo = np.array([(p.lower - (p.off or 0.0)) / p.typical for p in lin])
                hi = np.array([(p.upper - (p.off or 0.0)) / p.typical for p in lin])
                names = [p.name for p in lin]
            else:
                cols = [obj(term.apply(self.P0, start)) - r0]
                lo, hi, names = np.array([SHAPE_RANGE[0]]), np.array([SHAPE_RANGE[1]]), [""]
            self.screened[term.name] = Screened(term, start, np.column_stack(cols), lo, hi, names)

    # 2. rank ------------------------------------------------------------------------------------
    def rank_sets(self) -> None:
        """Every set of up to ``max_terms`` screened terms by the BIC of its bounded linear fit."""
        r0 = self._r0
        n = r0.size
        frac = effective_fraction(r0.reshape(len(self.replay.channels), -1))
        n_eff = n * frac
        names = list(self.screened)
        C = np.column_stack([self.screened[k].columns for k in names])
        G, g = C.T @ C, C.T @ r0
        where, k0 = {}, 0
        for k in names:
            m = self.screened[k].columns.shape[1]
            where[k] = list(range(k0, k0 + m))
            k0 += m
        rss0 = float(r0 @ r0)
        ranked = []
        for size in range(1, self.max_terms + 1):
            for combo in itertools.combinations(names, size):
                idx = [i for k in combo for i in where[k]]
                lo = np.concatenate([self.screened[k].lower for k in combo])
                hi = np.concatenate([self.screened[k].upper for k in combo])
                z = _bounded_quadratic(G[np.ix_(idx, idx)], g[idx], lo, hi)
                rss = max(rss0 + float(z @ G[np.ix_(idx, idx)] @ z) + 2.0 * float(g[idx] @ z), 1e-300)
                n_par = sum(len(self.screened[k].term.params) for k in combo)
                ranked.append((combo, n_eff * np.log(rss / n) + n_par * np.log(n_eff), z))
        ranked.sort(key=lambda c: c[1])
        self._coef = {c[0]: c[2] for c in ranked}
        self.ranked = [(c[0], float(c[1])) for c in ranked]

    # 3. refine ----------------------------------------------------------------------------------
    def refit(self, names: Sequence[str], near: SetFit | None = None) -> SetFit:
        """The set ``names`` fitted jointly over the fit part and scored on the held-out part (memoised);
        members of ``near`` (a fitted set it differs from by a term) start from their values there."""
        key = frozenset(names)
        if key in self.fitted:
            return self.fitted[key]
        terms = [t for t in self.terms if t.name in key]
        if terms:
            starts = self._starts(tuple(t.name for t in terms))
            if near is not None:
                have = {f.effect: f.params for f in near.fits}
                starts = [dict(have.get(t.name, s)) for t, s in zip(terms, starts, strict=True)]
            fits = fit_joint(self.replay, self.P0, terms, starts, self.n_train, self.tick)
            P = fits[-1].P
        else:
            fits, P = [], self.P0
        sim = self.replay.simulate(P)
        base = self.fitted.get(frozenset())
        frac = effective_fraction(self.replay.residual(base.sim if base else sim, self.hold))
        sc = score(self.replay, sim, self.hold, sum(len(t.params) for t in terms), frac)
        out = SetFit(tuple(t.name for t in terms), fits, P, sc, sim)
        self.fitted[key] = out
        return out

    def _starts(self, names: tuple[str, ...]) -> list[dict[str, float]]:
        """Each member's start: the set's linear coefficients if it was ranked, else each term's own."""
        z = next((v for k, v in self._coef.items() if set(k) == set(names)), None) if hasattr(self, "_coef") else None
        out, k0 = [], 0
        for name in names:
            s = self.screened.get(name)
            if s is None:
                t = next(t for t in self.terms if t.name == name)
                out.append(t.off())
                continue
            m = s.columns.shape[1]
            out.append(s.values(z[k0:k0 + m]) if z is not None else dict(s.start))
            k0 += m
        return out

    # 4. choose ----------------------------------------------------------------------------------
    def _prune(self, best: SetFit) -> SetFit:
        """Drop members that do not pay for themselves (module docstring, step 4), one at a time."""
        while best.names:
            now = score(self.replay, best.sim, self.hold, 0, 1.0)
            costs = {}
            for name, fit in zip(best.names, best.fits, strict=True):
                term = next(t for t in self.terms if t.name == name)
                if not relevant(self.replay, term, fit, best.sim, self.hold, now):
                    costs[name] = -np.inf
                    continue
                costs[name] = self.refit([n for n in best.names if n != name], best).score.bic - best.score.bic
            weakest = min(costs, key=lambda k: costs[k])
            if costs[weakest] >= MIN_DELTA_BIC:
                break
            best = self.refit([n for n in best.names if n != weakest], best)
        return best

    def _simpler_first(self, best: SetFit) -> SetFit:
        """A refinement (``Effect.refines``: a level per direction) that does not beat what it refines by
        ``MIN_DELTA_BIC`` gives way to it (its extra parameter does not pay for itself)."""
        names = {t.name for t in self.terms}
        for name in best.names:
            base = EFFECTS[name].refines if name in EFFECTS else ""
            if base and base in names and base not in best.names:
                alt = self.refit(tuple(base if n == name else n for n in best.names), best)
                if alt.score.bic - best.score.bic < MIN_DELTA_BIC:
                    return self._simpler_first(alt)
        return best

    def _parameter_first(self, best: SetFit) -> SetFit:
        """An effect of the set that a declared parameter replaces within the alias margin gives way."""
        kinds = {t.name: t.kind for t in self.terms}
        for name in [n for n in best.names if kinds[n] == "effect"]:
            for p in [t.name for t in self.terms if t.kind == "parameter" and t.name not in best.names]:
                if self._alike(name, p) < ALIKE:
                    continue  # the parameter moves the outputs otherwise: it cannot stand for the effect
                swapped = tuple(p if n == name else n for n in best.names)
                alt = self.refit(swapped, best)
                if alt.score.bic - best.score.bic < ALIAS_DELTA_BIC:
                    self.swaps.append((name, p))
                    return self._parameter_first(alt)
        return best

    def _alike(self, effect: str, parameter: str) -> float:
        """How much of the parameter's column lies in the span of the effect's columns (0 .. 1)."""
        a, b = self.screened.get(effect), self.screened.get(parameter)
        if a is None or b is None:
            return 0.0
        col = b.columns[:, 0]
        coef, *_ = np.linalg.lstsq(a.columns, col, rcond=None)
        n = float(np.linalg.norm(col))
        return float(np.linalg.norm(a.columns @ coef)) / n if n > 0 else 0.0

    def near_aliases(self) -> list[tuple[str, str, float]]:
        """(chosen term, other term, delta BIC) for refined sets of the chosen size differing in one term
        within ``ALIAS_DELTA_BIC``."""
        best = self.chosen
        if best is None or not best.names:
            return []
        out = []
        for key, s in self.fitted.items():
            if len(key) != len(best.names) or key == frozenset(best.names):
                continue
            gone, new = set(best.names) - set(key), set(key) - set(best.names)
            d = s.score.bic - best.score.bic
            if len(gone) == 1 and d < ALIAS_DELTA_BIC:
                a, b = gone.pop(), new.pop()
                if not nested(a, b):  # a refinement and what it refines are nested models, not aliases
                    out.append((a, b, float(d)))
        return out


def _bounded_quadratic(G: np.ndarray, g: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    """argmin z' G z + 2 g' z within bounds: the bounded least squares of the columns whose Gram
    matrix is ``G`` (through its Cholesky factor, a small problem whatever the record's length)."""
    k = g.size
    ridge = 1e-12 * max(float(np.trace(G)) / k, 1e-300)
    L = np.linalg.cholesky(G + ridge * np.eye(k))
    rhs = -np.linalg.solve(L, g)
    return lsq_linear(L.T, rhs, bounds=(lo, hi), method="bvls").x
