"""Continuous-time transfer-function identification from one input/output record (seed 001 sec 3.2).

Seed 001 fitted its Table 1 with MATLAB's ``tfest`` (instrument-variable initialisation, then
the default prediction-error refinement). python-control has no identifier, so this module does
the same two stages with scipy:

1. initial estimate by the state-variable-filter least-squares method (Young's SVF / the
   first step of SRIVC): input and output are filtered by s^k / (s + lambda)^n so that their
   derivatives exist, and the differential equation is solved for the coefficients by linear
   least squares, for a few filter bandwidths lambda (the best simulated fit is kept);
2. output-error refinement: ``scipy.optimize.least_squares`` minimises ||y - yhat|| with yhat
   the exact zero-order-hold simulation of the continuous model, i.e. maximises the fit %.

Fit % is MATLAB's NRMSE fit, 100 (1 - ||y - yhat|| / ||y - mean(y)||), and MSE = mean((y - yhat)^2).
Orders are compared with Akaike's criterion AIC = N ln(MSE) + 2 k (k = number of coefficients);
the smallest AIC is recommended. The record is assumed to start at rest with zero input meaning
rest (power off); the output's rest level (e.g. ambient temperature) is estimated with the model.
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from dataclasses import dataclass

import control
import numpy as np
from scipy import optimize, signal

__all__ = [
    "MIN_SAMPLES",
    "FitResult",
    "IdentificationError",
    "compare_orders",
    "fit_percent",
    "fit_tf",
    "format_table",
    "mean_squared_error",
    "recommend",
    "simulate_tf",
    "zoh_discretize",
]

MIN_SAMPLES = 50  # and at least 10 samples per estimated coefficient
FIT_SAMPLES = 2000  # longer records are block-averaged to about this many samples for the search


class IdentificationError(ValueError):
    """A record that cannot identify a model: too short, constant input or output, bad time base."""


@dataclass(frozen=True)
class FitResult:
    """One fitted model: numbers of poles and zeros, the transfer function and its scores."""

    n_poles: int
    n_zeros: int
    tf: control.TransferFunction
    fit_pct: float
    mse: float
    aic: float
    n_samples: int

    @property
    def poles(self) -> np.ndarray:
        return np.asarray(self.tf.poles())


def fit_percent(y: np.ndarray, yhat: np.ndarray) -> float:
    """MATLAB's NRMSE fit: 100 (1 - ||y - yhat|| / ||y - mean(y)||)."""
    y, yhat = np.asarray(y, float), np.asarray(yhat, float)
    return float(100.0 * (1.0 - np.linalg.norm(y - yhat) / np.linalg.norm(y - y.mean())))


def mean_squared_error(y: np.ndarray, yhat: np.ndarray) -> float:
    """mean((y - yhat)^2), as seed 001 reports with each chosen transfer function."""
    return float(np.mean((np.asarray(y, float) - np.asarray(yhat, float)) ** 2))


def _expm_small(M: np.ndarray) -> np.ndarray:
    """Matrix exponential of a small matrix: Taylor series of order 14 after scaling by 2^-s so that
    ||M 2^-s||_1 <= 1/2 (truncation error < 1e-16), then s squarings. Used instead of
    ``scipy.linalg.expm``, whose fixed overhead dominates the thousands of calls of a fit."""
    nrm = float(np.abs(M).sum(axis=0).max())
    if not np.isfinite(nrm):
        return np.full_like(M, np.nan)
    s = max(0, int(np.ceil(np.log2(nrm))) + 1) if nrm > 0 else 0
    X = M / 2.0**s
    E = np.eye(M.shape[0])
    term = np.eye(M.shape[0])
    for k in range(1, 15):
        term = term @ X / k
        E = E + term
    for _ in range(s):
        E = E @ E
    return E


def zoh_discretize(num: Sequence[float], den: Sequence[float], dt: float) -> tuple[np.ndarray, np.ndarray]:
    """Exact zero-order-hold equivalent (numerator, denominator in z^-1 powers) of the proper
    continuous transfer function num/den, through the controllable canonical state space."""
    den = np.asarray(den, float)
    num = np.asarray(num, float)
    a = den / den[0]
    b = np.concatenate([np.zeros(len(den) - len(num)), num]) / den[0]
    n = len(a) - 1
    M = np.zeros((n + 1, n + 1))
    M[0, :n] = -a[1:] * dt
    M[1:n, : n - 1] = np.eye(n - 1) * dt
    M[0, n] = dt
    Phi = _expm_small(M)
    Ad, Bd = Phi[:n, :n], Phi[:n, n]
    C = b[1:] - b[0] * a[1:]
    with np.errstate(all="ignore"):
        dend = np.real(np.poly(Ad)) if np.all(np.isfinite(Ad)) else np.full(n + 1, np.nan)
        numd = (np.real(np.poly(Ad - np.outer(Bd, C))) if np.all(np.isfinite(Ad)) else dend) + (b[0] - 1.0) * dend
    return numd, dend


def simulate_tf(num: Sequence[float], den: Sequence[float], u: np.ndarray, dt: float) -> np.ndarray:
    """Response of the continuous num/den from rest to ``u`` held over each sample (exact ZOH)."""
    numd, dend = zoh_discretize(num, den, dt)
    if not (np.all(np.isfinite(numd)) and np.all(np.isfinite(dend))):
        return np.full(np.shape(u), np.nan)
    return signal.lfilter(numd, dend, u)


def _check_record(t: np.ndarray, u: np.ndarray, y: np.ndarray, n_coeffs: int) -> float:
    """Validate the record and return its sample step."""
    if not (t.ndim == u.ndim == y.ndim == 1 and t.shape == u.shape == y.shape):
        raise IdentificationError(f"time, input and output must be 1-D of equal length, got {t.shape}, "
                                  f"{u.shape}, {y.shape}")
    need = max(MIN_SAMPLES, 10 * n_coeffs)
    if t.size < need:
        raise IdentificationError(f"record too short: {t.size} samples, need at least {need} "
                                  f"for {n_coeffs} coefficients")
    for name, v in (("time", t), ("input", u), ("output", y)):
        if not np.all(np.isfinite(v)):
            raise IdentificationError(f"{name} column has non-finite values")
    steps = np.diff(t)
    dt = float(np.median(steps))
    if dt <= 0 or np.max(np.abs(steps - dt)) > 1e-3 * dt:
        raise IdentificationError("time base must be uniformly sampled and increasing")
    if np.ptp(u) <= 1e-12 * max(1.0, float(np.max(np.abs(u)))):
        raise IdentificationError("input is constant: it excites nothing, no model can be identified")
    if np.ptp(y) <= 1e-12 * max(1.0, float(np.max(np.abs(y)))):
        raise IdentificationError("output is constant: nothing to fit")
    return dt


def _split(theta: np.ndarray, n_poles: int) -> tuple[np.ndarray, np.ndarray]:
    return theta[n_poles:], np.concatenate([[1.0], theta[:n_poles]])


def _svf_estimate(du: np.ndarray, dy: np.ndarray, dt: float, n_poles: int, n_zeros: int,
                  lam: float) -> np.ndarray:
    """State-variable-filter least squares: y^(n) + sum a_i y^(n-i) = sum b_j u^(m-j), with every
    signal filtered by 1 / (s + lam)^n so the derivatives s^k are realisable (k <= n)."""
    fden = np.poly(-lam * np.ones(n_poles)) / lam**n_poles

    def filt(x: np.ndarray, k: int) -> np.ndarray:
        num = np.zeros(k + 1)
        num[0] = 1.0
        return simulate_tf(num, fden, x, dt)

    yf = [filt(dy, k) for k in range(n_poles + 1)]
    uf = [filt(du, k) for k in range(n_zeros + 1)]
    cols = [-yf[n_poles - i] for i in range(1, n_poles + 1)] + [uf[n_zeros - j] for j in range(n_zeros + 1)]
    Phi = np.column_stack(cols)
    theta, *_ = np.linalg.lstsq(Phi, yf[n_poles], rcond=None)
    return theta


def fit_tf(t: np.ndarray, u: np.ndarray, y: np.ndarray, n_poles: int, n_zeros: int) -> FitResult:
    """Fit a continuous transfer function with ``n_poles`` poles and ``n_zeros`` zeros (seed 001
    Table 1 method: initial estimate, then output-error refinement); scores on the raw record."""
    if not (1 <= n_poles <= 6 and 0 <= n_zeros <= n_poles):
        raise IdentificationError(f"need 1 <= poles <= 6 and 0 <= zeros <= poles, got {n_poles}, {n_zeros}")
    t, u, y = (np.asarray(v, float) for v in (t, u, y))
    n_coeffs = n_poles + n_zeros + 1
    dt_full = _check_record(t, u, y, n_coeffs)
    u_full, y_full = u, y
    q = int(np.ceil(y.size / FIT_SAMPLES))
    if q > 1:  # the search runs on ~FIT_SAMPLES samples, the scores on the full record: the input
        k = (y.size // q) * q  # is averaged over each block (the held value), the output sampled at its start
        u, y = u[:k].reshape(-1, q).mean(axis=1), y[:k:q]
    dt = dt_full * q

    # theta = [a_1..a_n, b_0..b_m, y0]: the output offset y0 (rest level) is estimated too
    def residual(theta: np.ndarray) -> np.ndarray:
        num, den = _split(theta[:-1], n_poles)
        with np.errstate(all="ignore"):
            r = y - theta[-1] - simulate_tf(num, den, u, dt)
        return np.where(np.isfinite(r), r, 1e75)

    span = t[-1] - t[0]
    lams = np.geomspace(10.0 / span, 0.05 / dt, 6)
    starts = []
    for lam in lams:
        theta = np.append(_svf_estimate(u, y - y[0], dt, n_poles, n_zeros, float(lam)), y[0])
        if np.all(np.isfinite(theta)):
            starts.append((float(np.sum(residual(theta) ** 2)), theta))
    if not starts:
        raise IdentificationError("no initial estimate: the record does not determine the coefficients")
    starts.sort(key=lambda s: s[0])
    best = None
    for _, theta0 in starts[:1]:
        sol = optimize.least_squares(residual, theta0, x_scale="jac", method="lm", max_nfev=30 * n_coeffs)
        cost = float(np.sum(sol.fun**2))
        if best is None or cost < best[0]:
            best = (cost, sol.x)
    assert best is not None
    num, den = _split(best[1][:-1], n_poles)
    y = y_full
    yhat = best[1][-1] + simulate_tf(num, den, u_full, dt_full)
    err = mean_squared_error(y, yhat)
    return FitResult(
        n_poles=n_poles, n_zeros=n_zeros, tf=control.tf(num, den),
        fit_pct=fit_percent(y, yhat), mse=err,
        aic=float(y.size * np.log(max(err, 1e-300)) + 2 * n_coeffs), n_samples=int(y.size),
    )


def compare_orders(t: np.ndarray, u: np.ndarray, y: np.ndarray, orders: Iterable[int],
                   zeros: Iterable[int] | None = None) -> list[FitResult]:
    """Fit every order in ``orders`` with each number of zeros in ``zeros`` (default 0..order),
    as seed 001 Table 1 lists first- to third-order models with and without zeros."""
    wanted = None if zeros is None else sorted(set(zeros))
    results = []
    for n in sorted(set(orders)):
        for m in range(n + 1):
            if wanted is None or m in wanted:
                results.append(fit_tf(t, u, y, n, m))
    if not results:
        raise IdentificationError("no (order, zeros) combination to fit")
    return results


def recommend(results: Sequence[FitResult]) -> FitResult:
    """The model with the smallest AIC: the best fit after the penalty of 2 per coefficient."""
    return min(results, key=lambda r: r.aic)


def _poly(c: np.ndarray) -> str:
    n = len(c) - 1
    terms = []
    for i, v in enumerate(c):
        p = n - i
        s = "" if p == 0 else ("s" if p == 1 else f"s^{p}")
        terms.append(f"{v:.4g}" + (f" {s}" if s else ""))
    return " + ".join(terms).replace("+ -", "- ")


def format_table(results: Sequence[FitResult], input_name: str, output_name: str) -> str:
    """A seed 001 Table 1-style table: order, zeros, transfer function, fit %, MSE, AIC."""
    best = recommend(results)
    lines = [f"{output_name} : {input_name}  ({results[0].n_samples} samples)",
             f"{'poles':>5} {'zeros':>5} {'fit %':>7} {'MSE':>11} {'AIC':>12}  transfer function"]
    for r in results:
        num = np.atleast_1d(np.squeeze(r.tf.num[0][0]))
        den = np.atleast_1d(np.squeeze(r.tf.den[0][0]))
        mark = "  <- recommended (min AIC)" if r is best else ""
        lines.append(f"{r.n_poles:>5} {r.n_zeros:>5} {r.fit_pct:7.2f} {r.mse:11.4g} {r.aic:12.5g}  "
                     f"({_poly(num)}) / ({_poly(den)}){mark}")
    return "\n".join(lines)
