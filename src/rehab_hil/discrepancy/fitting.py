"""Fit one candidate effect's parameters to the measured outputs.

1. Start by regression on the residual, as seed 000 identifies k and c (Table 4): the columns
   are the output sensitivities to each linear parameter (one simulation at its typical value);
   the least-squares combination that cancels the nominal residual is the start. Shape
   parameters (a contact angle, a delay) are scanned over the effect's grid, keeping the best.
2. Refine on simulation error with ``scipy.optimize.least_squares`` (bounded, trust region).
3. Uncertainty from the Jacobian at the optimum: cov = s^2 (J^T J)^-1, inflated by n / n_eff for
   the autocorrelation of the residual (``selection.effective_fraction``).
"""

from __future__ import annotations

import itertools
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
from scipy.optimize import least_squares

from rehab_hil.discrepancy.replay import Replay
from rehab_hil.discrepancy.selection import effective_fraction
from rehab_hil.effects import Effect, EffectParam

__all__ = ["Fit", "fit_effect"]

# Finite-difference step on parameters scaled by their typical value: large enough to see through
# encoder quantisation and stick-slip switching, which make the simulated error piecewise flat.
DIFF_STEP = 0.05
BLOWUP = 1e3  # scaled residual that stands for a diverged simulation
MAX_NFEV = 8  # per fitted parameter beyond the first, 6 more (shape parameters start far off)


@dataclass
class Fit:
    """A fitted effect: values, standard errors, the regression start and the training cost."""

    effect: str
    params: dict[str, float]
    stderr: dict[str, float]
    start: dict[str, float]
    train_cost: float
    n_simulations: int
    P: np.ndarray = field(repr=False)


def fit_effect(replay: Replay, base: np.ndarray, effect: Effect, n_train: int,
               tick: Callable[[], None] | None = None) -> Fit:
    """Fit ``effect`` on the first ``n_train`` measured samples, other parameters as in ``base``."""
    count = [0]

    def residual(values: dict[str, float]) -> np.ndarray:
        count[0] += 1
        if tick:
            tick()
        P = replay.with_effects(base, {effect.name: values})
        r = replay.residual(replay.simulate(P, n_train), slice(0, n_train)).ravel()
        # a candidate that makes the model diverge is a bad fit, not a crash
        return np.clip(np.nan_to_num(r, nan=BLOWUP, posinf=BLOWUP, neginf=-BLOWUP), -BLOWUP, BLOWUP)

    r0 = replay.residual(replay.simulate(base, n_train), slice(0, n_train)).ravel()
    count[0] += 1
    params = effect.params_for(replay.ports)
    start = _regression_start(effect, params, residual, r0)
    names = [p.name for p in params]
    typ = np.array([p.typical for p in params])
    lo = np.array([p.lower for p in params]) / typ
    hi = np.array([p.upper for p in params]) / typ
    z0 = np.clip(np.array([start[n] for n in names]) / typ, lo, hi)

    def fun(z: np.ndarray) -> np.ndarray:
        return residual(dict(zip(names, z * typ, strict=True)))

    sol = least_squares(fun, z0, bounds=(lo, hi), diff_step=DIFF_STEP, max_nfev=MAX_NFEV + 6 * (len(names) - 1),
                        xtol=1e-3, ftol=1e-4, x_scale=1.0)
    z = sol.x
    values = dict(zip(names, (z * typ).tolist(), strict=True))
    stderr = _stderr(sol.jac, sol.fun, typ, replay, n_train)
    return Fit(effect.name, values, dict(zip(names, stderr, strict=True)), start,
               float(np.mean(sol.fun**2)), count[0],
               replay.with_effects(base, {effect.name: values}))


def _regression_start(effect: Effect, params: tuple[EffectParam, ...],
                      residual: Callable[[dict[str, float]], np.ndarray], r0: np.ndarray) -> dict[str, float]:
    """Best start over the grid of shape parameters; linear ones by regression on the residual."""
    lin = [p for p in params if p.linear]
    shape = [p for p in params if not p.linear]
    off = effect.disabled()
    best: tuple[float, dict[str, float]] | None = None
    for combo in itertools.product(*[p.grid or (p.typical,) for p in shape]):
        values = {**off, **{p.name: v for p, v in zip(shape, combo, strict=True)}}
        if lin:
            cols = []
            for p in lin:
                r = residual({**values, p.name: p.typical})
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


def _stderr(jac: np.ndarray, res: np.ndarray, typ: np.ndarray, replay: Replay, n_train: int) -> list[float]:
    """Standard errors from the Jacobian (scaled back to SI), inflated for correlated residuals."""
    n, k = res.size, typ.size
    s2 = float(res @ res) / max(n - k, 1)
    frac = effective_fraction(res.reshape(len(replay.channels), n_train))
    try:
        cov = np.linalg.pinv(jac.T @ jac) * s2 / frac
    except np.linalg.LinAlgError:
        return [float("nan")] * k
    se = np.sqrt(np.clip(np.diag(cov), 0.0, None)) * typ
    se[np.linalg.norm(jac, axis=0) == 0.0] = np.nan  # the data say nothing about this parameter
    return se.tolist()
