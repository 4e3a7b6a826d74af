"""Fit candidate terms (library effects or nominal parameters) to the measured outputs.

A term is anything with bounded parameters that edits the parameter vector: a library effect
(its part's parameters) or a declared nominal parameter (``parameters.py``, a relative error).

1. A new term starts by regression on the residual, as seed 000 identifies k and c (Table 4): the
   columns are the output sensitivities to each linear parameter (one simulation at its typical
   value); the least-squares combination that cancels the residual is the start. Shape
   parameters (a contact angle, a delay) are scanned over the term's grid plus any seeds (the
   delay: the lag signature of the localisation), keeping the best.
2. Refine on the replay's error (open loop or shooting, ``shooting.py``) with
   ``scipy.optimize.least_squares`` (bounded, trust region). ``fit_joint`` refits several chosen
   terms together from their current values.
3. Uncertainty from the Jacobian at the optimum: cov = s^2 (J^T J)^-1, inflated by n / n_eff for
   the autocorrelation of the residual (``selection.effective_fraction``).
"""

from __future__ import annotations

import itertools
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field

import numpy as np
from scipy.optimize import least_squares

from rehab_hil.discrepancy.parameters import ERROR_PARAM, ParameterTerm
from rehab_hil.discrepancy.replay import Replay
from rehab_hil.discrepancy.selection import bounded, effective_fraction
from rehab_hil.effects import Effect, EffectParam

__all__ = ["MIN_MAGNITUDE_SHARE", "MIN_PARAMETER_ERROR", "Fit", "Objective", "Term", "effect_term", "fit_joint",
           "fit_term", "parameter_term", "regression_start"]

# Finite-difference step on parameters scaled by their typical value: large enough to see through
# encoder quantisation and stick-slip switching, which make the simulated error piecewise flat.
DIFF_STEP = 0.05
MAX_NFEV = 8  # per fitted parameter beyond the first, 6 more (shape parameters start far off)
# A fitted effect smaller than this share of its typical magnitude (a 0.02-count sensor offset) or a
# parameter off by less than MIN_PARAMETER_ERROR (within a config's accuracy; an open-loop replay can
# trade a 0.5 % spring change against a slow drift) is a rounding of "off", never reported.
MIN_MAGNITUDE_SHARE = 0.5  # the smallest effect worth reporting: half its typical magnitude
MIN_PARAMETER_ERROR = 0.03


@dataclass(frozen=True)
class Term:
    """A candidate: name, kind ("effect" or "parameter"), bounded parameters, and how its values
    edit a parameter vector."""

    name: str
    kind: str
    params: tuple[EffectParam, ...]
    apply: Callable[[np.ndarray, Mapping[str, float]], np.ndarray]

    def off(self) -> dict[str, float]:
        return {p.name: (p.off if p.off is not None else p.typical) for p in self.params}

    def relevant(self, values: Mapping[str, float]) -> bool:
        """Is the fitted term more than a rounding of "off"? An effect needs some magnitude
        parameter at least ``MIN_MAGNITUDE_SHARE`` of its typical value away from off; a parameter
        must be off by at least ``MIN_PARAMETER_ERROR``."""
        if self.kind == "parameter":
            return abs(values[ERROR_PARAM.name]) >= MIN_PARAMETER_ERROR
        return any(abs(values[p.name] - p.off) >= MIN_MAGNITUDE_SHARE * p.typical
                   for p in self.params if p.off is not None)


def effect_term(replay: Replay, effect: Effect) -> Term:
    """A library effect as a term (typical magnitudes of the port it attaches to)."""
    return Term(effect.name, "effect", effect.params_for(replay.ports),
                lambda P, v: replay.with_effects(P, {effect.name: v}))


def parameter_term(term: ParameterTerm) -> Term:
    """A declared nominal parameter as a term: one relative error."""
    return Term(term.name, "parameter", (ERROR_PARAM,), term.apply)


@dataclass
class Fit:
    """A fitted term: values, standard errors, the regression start and the training cost."""

    effect: str  # the term's name (an effect, or a parameter's config key)
    params: dict[str, float]
    stderr: dict[str, float]
    start: dict[str, float]
    train_cost: float
    n_simulations: int
    P: np.ndarray = field(repr=False)
    kind: str = "effect"


class Objective:
    """The weighted scaled residual of a parameter vector on the fit part (what the fits minimise),
    a diverged run bounded (``selection.bounded``); ``count`` runs so far, ``tick`` called on each."""

    def __init__(self, replay: Replay, n_train: int, tick: Callable[[], None] | None) -> None:
        self.replay, self.n_train, self.tick, self.count = replay, n_train, tick, 0

    def __call__(self, P: np.ndarray) -> np.ndarray:
        self.count += 1
        if self.tick:
            self.tick()
        r = self.replay.residual(self.replay.simulate(P, self.n_train, sensed=False),
                                  slice(self.replay.fit_start, self.n_train), weighted=True).ravel()
        return bounded(r)


def fit_term(replay: Replay, base: np.ndarray, term: Term, n_train: int,
             tick: Callable[[], None] | None = None, seeds: Mapping[str, Sequence[float]] | None = None) -> Fit:
    """Fit ``term`` alone on the first ``n_train`` samples, everything else as in ``base``."""
    obj = Objective(replay, n_train, tick)
    r0 = obj(base)
    start = regression_start(term, lambda v: obj(term.apply(base, v)), r0, seeds or {})
    fits = _refine(replay, base, [term], [start], obj)
    fits[0].start = start
    return fits[0]


def fit_joint(replay: Replay, base: np.ndarray, terms: Sequence[Term], values: Sequence[Mapping[str, float]],
              n_train: int, tick: Callable[[], None] | None = None) -> list[Fit]:
    """Refit several terms together, starting from ``values``; ``base`` has them switched off."""
    obj = Objective(replay, n_train, tick)
    return _refine(replay, base, list(terms), [dict(v) for v in values], obj)


def _refine(replay: Replay, base: np.ndarray, terms: list[Term], starts: list[dict[str, float]],
            obj: Objective) -> list[Fit]:
    layout = [(t, p) for t in terms for p in t.params]
    typ = np.array([p.typical for _, p in layout])
    lo = np.array([p.lower for _, p in layout]) / typ
    hi = np.array([p.upper for _, p in layout]) / typ
    z0 = np.clip(np.array([s[p.name] for t, s in zip(terms, starts, strict=True) for p in t.params]) / typ, lo, hi)

    def build(z: np.ndarray) -> np.ndarray:
        P, k = base, 0
        for t in terms:
            P = t.apply(P, {p.name: float(z[k + j] * typ[k + j]) for j, p in enumerate(t.params)})
            k += len(t.params)
        return P

    sol = least_squares(lambda z: obj(build(z)), z0, bounds=(lo, hi), diff_step=DIFF_STEP,
                        max_nfev=MAX_NFEV + 6 * (len(layout) - 1), xtol=1e-3, ftol=1e-4, x_scale=1.0)
    se = _stderr(sol.jac, sol.fun, typ, len(obj.replay.channels), obj.n_train - obj.replay.fit_start)
    P = build(sol.x)
    out, k = [], 0
    for t, s in zip(terms, starts, strict=True):
        names = [p.name for p in t.params]
        vals = {n: float(sol.x[k + j] * typ[k + j]) for j, n in enumerate(names)}
        errs = {n: float(se[k + j]) for j, n in enumerate(names)}
        out.append(Fit(t.name, vals, errs, dict(s), float(np.mean(sol.fun**2)), obj.count, P, t.kind))
        k += len(names)
    return out


def regression_start(term: Term, residual: Callable[[dict[str, float]], np.ndarray], r0: np.ndarray,
                      seeds: Mapping[str, Sequence[float]]) -> dict[str, float]:
    """Best start over the grid of shape parameters; linear ones by regression on the residual."""
    lin = [p for p in term.params if p.linear]
    shape = [p for p in term.params if not p.linear]
    off = term.off()
    best: tuple[float, dict[str, float]] | None = None
    grids = [sorted({*(p.grid or (p.typical,)), *(v for v in seeds.get(p.name, ()) if p.lower < v <= p.upper)})
             for p in shape]
    for combo in itertools.product(*grids):
        values = {**off, **{p.name: v for p, v in zip(shape, combo, strict=True)}}
        if lin:
            cols = []
            for p in lin:
                r = residual({**values, p.name: (p.off or 0.0) + p.typical})
                cols.append((r - r0) / p.typical)
            S = np.column_stack(cols)
            coef, *_ = np.linalg.lstsq(S, -r0, rcond=None)
            coef = np.clip(coef, [p.lower for p in lin], [p.upper for p in lin])
            values.update({p.name: float(c) for p, c in zip(lin, coef, strict=True)})
            cost = float(np.mean((r0 + S @ coef) ** 2))  # predicted by the regression: no extra run
        else:
            cost = float(np.mean(residual(values) ** 2))
        if best is None or cost < best[0]:
            best = (cost, values)
    assert best is not None
    return best[1]


def _stderr(jac: np.ndarray, res: np.ndarray, typ: np.ndarray, n_channels: int, n_train: int) -> list[float]:
    """Standard errors from the Jacobian (scaled back to SI), inflated for correlated residuals."""
    n, k = res.size, typ.size
    s2 = float(res @ res) / max(n - k, 1)
    frac = effective_fraction(res.reshape(n_channels, n_train))
    try:
        cov = np.linalg.pinv(jac.T @ jac) * s2 / frac
    except np.linalg.LinAlgError:
        return [float("nan")] * k
    se = np.sqrt(np.clip(np.diag(cov), 0.0, None)) * typ
    se[np.linalg.norm(jac, axis=0) == 0.0] = np.nan  # the data say nothing about this parameter
    return se.tolist()
