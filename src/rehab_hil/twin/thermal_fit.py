"""One window's fit of the thermal quantities (``twin/thermal.py``): Levenberg-Marquardt on the
weighted prediction error plus the previous window's estimate as prior, from the best of a few starts,
with finite-difference sensitivities through the whole model; and the statistics it weighs by (each
channel's residual variance widened for its AR(1) correlation)."""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np

__all__ = ["WindowFit", "explains", "grown_covariance", "residual_weights", "rms"]

NUDGE = 0.002  # finite-difference step of a relative quantity: the SMA's error valley is narrow (0.5 C off
# the room's temperature moves the angle by 2.6 counts RMS over a cycle), and a step of 0.02 (0.46 C) read
# slopes across it: a 5 C colder room was found at 21.0 C with it, at 18.01 C with 0.002
MAX_ITER = 12  # Levenberg-Marquardt steps per window at most ...
TOL = 1e-3  # ... while the estimate moves more than this (relative)
START_SPREAD = 1.5  # the fit's other starts: each quantity moved by this many prior spreads
DESCENTS = 2  # descents from the best of the starts; the lowest cost is kept
MU0, MU_MAX = 1e-3, 1e4  # Levenberg-Marquardt damping: its start (and floor) and where a step is given up
EXPLAINED_COUNTS = 2.0  # a fit that leaves at most this RMS on a channel explains it [counts] ...
EXPLAINED_SHARE = 0.1  # ... or this share of the RMS the previous estimate left
BOUNDS = (0.3, 3.0)  # the estimate stays within these multiples of the config value
MIN_VARIANCE_COUNTS2 = 1.0 / 12.0  # a residual variance is never taken below a count's quantisation


class WindowFit:
    """The fit of one window: ``predict(theta)`` gives the window's kept samples (counts) with the
    quantities at ``theta`` (relative to the config), ``z`` the measured ones, ``ok`` which are finite."""

    def __init__(self, predict: Callable[[np.ndarray], np.ndarray], z: np.ndarray, ok: np.ndarray,
                 prior: np.ndarray, prior_info: np.ndarray) -> None:
        self.predict, self.z, self.ok = predict, z, ok
        self.prior, self.prior_info = prior, prior_info

    def best(self) -> tuple[np.ndarray, np.ndarray]:
        """Descents from the best ``DESCENTS`` starts (the angle is flat outside the wire's transformation
        band, and a descent from one start can stop where the wire crosses the band at the wrong times),
        compared with one set of weights (those of the end that predicts the samples best); the lowest
        cost's end and its predicted samples."""
        ends = [self.descend(start) for start in self.starts()[:DESCENTS]]
        sse = [float(np.nansum((self.z - y) ** 2)) for _, y in ends]
        w = residual_weights(self.z - ends[int(np.argmin(sse))][1], self.ok)
        return min(ends, key=lambda ty: self.cost(self.z - ty[1], w, ty[0]))

    def starts(self) -> list[np.ndarray]:
        """The prior and each quantity alone moved by +-START_SPREAD of its prior spread, best first
        (cost with the prior point's residual weights)."""
        w = residual_weights(self.z - self.predict(self.prior), self.ok)
        sd = np.sqrt(np.diag(np.linalg.inv(self.prior_info)))
        cands = [self.prior.copy()]
        for j in range(self.prior.size):
            for sign in (-1.0, 1.0):
                th = self.prior.copy()
                th[j] = np.clip(th[j] + sign * START_SPREAD * sd[j], *BOUNDS)
                cands.append(th)
        costs = [self.cost(self.z - self.predict(th), w, th) for th in cands]
        return [cands[k] for k in np.argsort(costs)]

    def descend(self, theta: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Levenberg-Marquardt from ``theta``: a step is taken only where it lowers the cost (the
        hysteresis makes the error far from smooth). The end point and its predicted samples."""
        mu = MU0
        y = self.predict(theta)
        for _ in range(MAX_ITER):
            w = residual_weights(self.z - y, self.ok)  # this point's residual variance weighs data against prior
            A, b = self._weighted(self.jacobian(theta, y), self.z - y, w)
            H = A.T @ A + self.prior_info
            g = A.T @ b + self.prior_info @ (self.prior - theta)
            cost = self.cost(self.z - y, w, theta)
            while mu < MU_MAX:
                new = np.clip(theta + np.linalg.solve(H + mu * np.diag(np.diag(H)), g), *BOUNDS)
                y_new = self.predict(new)
                if self.cost(self.z - y_new, w, new) < cost:
                    break
                mu *= 4.0
            else:
                break  # no step lowers the cost: at the minimum
            moved = float(np.max(np.abs(new - theta)))
            theta, y, mu = new, y_new, max(mu / 4.0, MU0)
            if moved < TOL:
                break
        return theta, y

    def covariance(self, theta: np.ndarray, y: np.ndarray) -> np.ndarray:
        """The posterior covariance at ``theta`` (the end's residual weights, the prior's information)."""
        A, _ = self._weighted(self.jacobian(theta, y), self.z - y, residual_weights(self.z - y, self.ok))
        return np.linalg.inv(A.T @ A + self.prior_info)

    def cost(self, e: np.ndarray, w: np.ndarray, theta: np.ndarray) -> float:
        """The weighted squared prediction error plus the prior's term."""
        d = theta - self.prior
        ok = self.ok
        return float(sum(w[c] * np.sum(e[ok[:, c], c] ** 2) for c in range(e.shape[1])) + d @ self.prior_info @ d)

    def jacobian(self, theta: np.ndarray, y: np.ndarray) -> np.ndarray:
        """d predicted sample / d quantity (samples x channels x quantities, in counts), by forward
        differences through the whole window."""
        J = np.empty((*y.shape, theta.size))
        for j in range(theta.size):
            th = theta.copy()
            th[j] += NUDGE
            J[..., j] = (self.predict(th) - y) / NUDGE
        return J

    def _weighted(self, J: np.ndarray, e: np.ndarray, w: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The finite rows of the sensitivities and the residuals, each channel scaled by sqrt(weight)."""
        ok, channels = self.ok, range(e.shape[1])
        A = np.vstack([J[ok[:, c], c, :] * math.sqrt(w[c]) for c in channels])
        b = np.concatenate([e[ok[:, c], c] * math.sqrt(w[c]) for c in channels])
        return A, b


def residual_weights(e: np.ndarray, ok: np.ndarray) -> np.ndarray:
    """Per channel: 1 / (residual variance widened for the residuals' correlation, AR(1))."""
    w = np.zeros(e.shape[1])
    for c in range(e.shape[1]):
        r = e[ok[:, c], c]
        if r.size < 3:
            continue
        var = max(float(np.mean(r**2)), MIN_VARIANCE_COUNTS2)
        d = r - r.mean()
        rho = float(np.clip(np.sum(d[1:] * d[:-1]) / max(float(np.sum(d * d)), 1e-300), 0.0, 0.95))
        w[c] = 1.0 / (var * (1.0 + rho) / (1.0 - rho))
    return w


def grown_covariance(cov: np.ndarray, lam: float, prior_cov: np.ndarray) -> np.ndarray:
    """The previous covariance grown by the forgetting factor ``lam``, each variance at most the prior's (a
    quantity the windows say nothing about keeps its prior spread instead of growing without end)."""
    C = cov / lam
    d = np.sqrt(np.minimum(1.0, np.diag(prior_cov) / np.maximum(np.diag(C), 1e-300)))
    return C * np.outer(d, d)


def explains(before: np.ndarray, after: np.ndarray) -> bool:
    """The fitted thermal quantities explain the window: on every channel the RMS left is within
    ``EXPLAINED_COUNTS`` or a ``EXPLAINED_SHARE`` of what the previous estimate left. A difference that
    is not thermal (the SMA wire's pre-strain 15 % lower: 39.5 counts at the config, 13.5 after the fit;
    a warm room: 30.5 -> 0.35) is not handed to the controller as one."""
    return bool(np.all((after <= EXPLAINED_COUNTS) | (after <= EXPLAINED_SHARE * before)))


def rms(e: np.ndarray) -> np.ndarray:
    """Per channel: the RMS of the finite residuals (counts)."""
    return np.sqrt(np.nanmean(e**2, axis=0))
