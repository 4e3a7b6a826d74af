"""Online estimate of the patient's interaction parameters: recursive least squares with forgetting
on the model's own prediction error (a recursive prediction-error method, Ljung & Soderstrom 1983).

Seed 000 identifies the human-machine contact's stiffness k and damping c (Table 4, eq 30) offline,
by multiple linear regression of the measured contact force on the pad's deformation and its rate.
Online, on a rig that measures an angle (and maybe a force), the same parameters are those of the
model's torque balance: the twin's model with the estimated values is run over each re-anchored
segment, and once more per parameter with that parameter nudged, which gives the sensitivity of
every predicted sample to every parameter (finite differences through the whole plant: contact,
passive joint, actuator and controller-applied effort alike). The model reads an encoder angle
before its quantisation (``TwinModel(smooth=True)``): a 5 % nudge moves a prediction by less than
a count, and whole counts have no slope. The segment's prediction error then updates the estimate
by RLS with exponential forgetting (memory ``forgetting_s``), the update re-linearised while the
estimate moves (an iterated extended Kalman filter's update), and the model's unmeasured states
carried on as if it had run on the new estimate. A segment far outside anything seen before (an
abrupt change: a patient's stiffness doubling) restarts the covariance, so the change is followed
in a few segments instead of a few memories. Parameters are estimated relative to their config
value (1 = the config), which keeps the problem well scaled; the 95 % interval comes from the RLS
covariance times the residual variance. Per session, the segments since the start (or the last
restart) are fitted again together, without forgetting: Gauss-Newton from the running estimate.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from rehab_hil.discrepancy.replay import CANDIDATE_PREFIX
from rehab_hil.twin.model import TwinModel, TwinSetupError

__all__ = ["Estimate", "InteractionEstimator", "default_estimates", "estimate_report", "resolve_parameters"]

NUDGE = 0.05  # finite-difference step: this share of the parameter's config value
SUBSAMPLE = 5  # every this many samples of a segment enter the regression (neighbours are correlated)
P0 = 1.0  # initial covariance of the relative parameters (a prior of +/-100 %)
BOUNDS = (0.02, 20.0)  # the estimate stays within these multiples of the config value
RESTART_SIGMAS = 10.0  # a segment whose prediction error RMS exceeds this many running residual sigmas restarts
ITERATE_SIGMAS = 3.0  # a segment whose prediction error RMS exceeds this many sigmas gets an iterated update
MAX_ITER = 5  # re-linearisations of one update at most ...
ITER_TOL = 0.02  # ... while the estimate moves more than this (relative to the config value)
SESSION_SEGMENTS = 1200  # the session estimate fits at most this many segments, spread over the session (5 min of
# 0.25 s segments; a longer session keeps every 2nd, 4th ... of them): the fit at its end stays within seconds
SESSION_ITER = 4  # Gauss-Newton steps of the session estimate at most ...
SESSION_TOL = 1e-3  # ... while it moves more than this (relative)
EFFECT_PREFIX = "effect_"


@dataclass
class Estimate:
    """One parameter's online estimate."""

    name: str  # as configured (``[twin] estimate``)
    value: float  # SI
    ci95: float  # half-width of the 95 % interval, SI
    nominal: float  # the config's value, SI


def resolve_parameters(model: TwinModel, names: Sequence[str]) -> list[list[int]]:
    """The diagram parameter indices each name stands for: ``part.param`` exactly, or a configured
    effect's ``effect.param``. A plant parameter takes every other plant part's parameter of the same
    name and value with it (the SMA's pad and contact-force parts share k and c); a configured
    effect's stands alone (a contact damping of 0.02 is not the iris's viscous damping of 0.02).
    Unknown names are refused."""
    d = model.system.diagram
    names_all = d.param_names
    out: list[list[int]] = []
    for name in names:
        _, _, param = name.partition(".")
        found = [q for q in (name, f"{EFFECT_PREFIX}{name}") if q in names_all]
        if not found or not param:
            known = [n for n in names_all if not n.startswith(CANDIDATE_PREFIX)]
            raise TwinSetupError(f"estimate {name!r}: no such model parameter (part.param); the model has "
                                 f"{', '.join(known[:12])}{' ...' if len(known) > 12 else ''}")
        i0 = d.param_index(found[0])
        v0 = model.P[i0]
        # a configured effect's parameter is its own; a plant's may be built into several parts
        idx = [i0] if found[0].startswith(EFFECT_PREFIX) else [i0] + [
            i for i, q in enumerate(names_all) if i != i0 and q.split(".", 1)[1] == param
            and not q.startswith((CANDIDATE_PREFIX, EFFECT_PREFIX)) and model.P[i] == v0]
        if v0 == 0.0:
            raise TwinSetupError(f"estimate {name!r}: its config value is 0; the estimate is relative to it")
        out.append(idx)
    return out


def default_estimates(model: TwinModel) -> list[str]:
    """Without ``[twin] estimate``: the stiffness and damping of a contact the config adds to the model
    (``[[effects]]`` contact_spring_damper), else nothing."""
    names = model.system.diagram.param_names
    eff = f"{EFFECT_PREFIX}contact_spring_damper"
    return [f"contact_spring_damper.{p}" for p in ("stiffness_nm_per_rad", "damping_nm_s_per_rad")
            if f"{eff}.{p}" in names]


class InteractionEstimator:
    """RLS with forgetting on the twin's segments; ``update`` per segment, ``estimates`` any time."""

    def __init__(self, model: TwinModel, names: Sequence[str], forgetting_s: float) -> None:
        """``model``: a ``TwinModel`` of the estimator's own (its parameters become the estimate)."""
        self.model, self.names = model, list(names)
        self.index = resolve_parameters(model, self.names)
        self.nominal = np.array([model.P[ix[0]] for ix in self.index])
        self.theta = np.ones(len(self.names))  # relative to the config value
        self.cov = np.eye(len(self.names)) * P0
        self.lam = math.exp(-model.segment_samples * model.period_s / forgetting_s)
        self.sigma2 = 1.0  # running residual variance (normalised units)
        self.updates = 0
        self.P = model.P  # the estimator's model runs on the estimate
        self._out_jac = model.output_jacobian(model.x, model.xd, model.inputs_of(0, 0, 0, {}))
        self._apply(self.P, self.theta)
        self.restarts = -1
        self.restart(0.0)

    def restart(self, t_s: float) -> None:
        """Forget what the estimate has learned (an abrupt change): the covariance back to its prior
        and the session's least squares begun again from ``t_s``."""
        n = self.theta.size
        self.cov = np.eye(n) * P0
        self._prior = self.theta.copy()  # where the estimate (re)started
        self._segments: list[tuple[np.ndarray, ...]] = []  # every ``_stride``-th whole segment since t_s
        self._stride, self._seen = 1, 0
        self._dx_start = np.zeros((self.model.x.size, n))  # d (next segment's start state) / d estimate
        self.session_start_s = t_s
        self.restarts += 1

    def session_estimates(self) -> list[Estimate]:
        """The session's estimate: regularised nonlinear least squares (Gauss-Newton from the running
        estimate, with the running estimate's own prior) over the whole segments since the session
        began or the estimate last restarted (at most ``SESSION_SEGMENTS``, spread over that time),
        each from the start state the estimator's model had, with its 95 % interval; the running
        estimate where there is not enough to fit."""
        segs = self._segments
        n = self.theta.size
        if len(segs) < 2:
            return self.estimates()
        theta = self.theta.copy()
        for _ in range(SESSION_ITER):
            R, r, sse, rows = np.zeros((n, n)), np.zeros(n), 0.0, 0
            for x0, xd0, steps, at, z, then, dx0 in segs:
                x = x0 + dx0 @ (theta - then)
                y, x_end = self._predict(theta, x, xd0, steps, at)
                phi, _ = self._sensitivity(theta, x, xd0, steps, at, y, x_end)
                e = (z - y).ravel()
                R += phi.T @ phi
                r += phi.T @ e
                sse += float(e @ e)
                rows += e.size
            # the running estimate's prior (the config, or the value it restarted from, +-sqrt(P0)) weighs
            # in as it does there: a session that says little about a parameter leaves it near the prior
            R += np.eye(n) / P0
            r += (self._prior - theta) / P0
            try:
                step = np.linalg.solve(R, r)
                cov = np.linalg.inv(R)
            except np.linalg.LinAlgError:
                return self.estimates()
            if not np.all(np.isfinite(step)):
                return self.estimates()
            new = np.clip(theta + step, *BOUNDS)
            moved = float(np.max(np.abs(new - theta)))
            theta = new
            if moved < SESSION_TOL:
                break
        sd = np.sqrt(np.maximum(np.diag(cov), 0.0) * sse / max(rows - n, 1))
        return [Estimate(nm, float(v0 * t), float(1.96 * v0 * d), float(v0))
                for nm, v0, t, d in zip(self.names, self.nominal, theta, sd, strict=True)]

    def _apply(self, P: np.ndarray, theta: np.ndarray) -> None:
        for ix, v0, th in zip(self.index, self.nominal, theta, strict=True):
            P[ix] = v0 * th

    def update(self, index: np.ndarray, U: np.ndarray, measured: np.ndarray) -> None:
        """One segment of samples (as ``TwinModel.advance`` takes them): predict it with the current
        estimate from the estimator's own re-anchored state, and update the estimate (on a whole
        segment with no sample lost)."""
        m = self.model
        whole = (index.size == m.segment_samples and int(index[-1] - index[0]) == index.size - 1
                 and m.at_anchor)
        if not m.anchored or not whole:
            # a partial segment or one with samples lost: the inputs over a gap are not known, so its
            # prediction error says nothing sure about the patient (the model still carries on)
            m.advance(index, U, measured)
            self._dx_start = np.zeros_like(self._dx_start)
            return
        x0, xd0 = m.x.copy(), m.xd.copy()
        steps, at = m.plan(index, U)
        y_all = m.advance(index, U, measured).predicted
        keep = np.arange(0, at.size, SUBSAMPLE)
        if keep.size < 2 or not np.all(np.isfinite(measured[keep])) or not np.all(np.isfinite(y_all)):
            return
        at = at[keep]
        z = measured[keep] / m.resolution
        pinned = np.any(m.anchor_gain != 0.0, axis=0)  # channels whose states the anchoring sets
        prior, y = self.theta.copy(), y_all[keep] / m.resolution
        if self.updates and float(np.mean((z - y) ** 2)) > RESTART_SIGMAS**2 * self.sigma2:
            self.restart(float(index[0] * m.period_s))
        x_end = m.x - m.anchor_gain @ m.last_correction  # the segment's end before its anchoring
        # an iterated update (as the iterated extended Kalman filter's) where the segment is far from the
        # estimate's prediction: re-linearised at each new estimate while it moves, so a large change (a
        # stiffness doubling) is not read off a slope taken far from it; near it, one step
        far = not self.updates or float(np.mean((z - y) ** 2)) > ITERATE_SIGMAS**2 * self.sigma2
        step = self._rls_step(prior, (x0, xd0, steps, at), z, y, x_end, far)
        if step is None:
            return
        theta, cov, dx, r = step
        # anchoring sets the states a channel is to its measurement: those no longer depend on the estimate
        if np.any(pinned):
            dx -= m.anchor_gain[:, pinned] @ (self._out_jac[pinned] @ dx)
        # the start state depends on the estimate too (an unmeasured pad deformation follows the contact's
        # stiffness): kept with its sensitivity, so the session's fit starts each segment where the
        # estimate it tries would have put it
        self._remember((x0, xd0, steps, at, z, prior, self._dx_start))
        self._dx_start = dx
        m.x += dx @ (theta - prior)  # the estimator's model carries on as if it had run on the new estimate
        self.theta = theta
        self.cov = 0.5 * (cov + cov.T)
        self.sigma2 = self.lam * self.sigma2 + (1 - self.lam) * float(np.mean(r**2)) if self.updates \
            else float(np.mean(r**2))
        self.updates += 1
        self._apply(self.P, self.theta)

    def _rls_step(self, prior: np.ndarray, segment: tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray],
                  z: np.ndarray, y: np.ndarray, x_end: np.ndarray, far: bool
                  ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray] | None:
        """The RLS update of the estimate ``prior`` on one segment (``segment`` = start state, discrete
        start state, steps, sample positions; ``z`` measured, ``y`` predicted), iterated while ``far``:
        (estimate, covariance, d end state / d estimate, residual), or None when it cannot be taken."""
        x0, xd0, steps, at = segment
        theta, C, lam = prior.copy(), self.cov, self.lam
        for it in range(MAX_ITER if far else 1):
            phi, dx = self._sensitivity(theta, x0, xd0, steps, at, y, x_end)
            if not np.all(np.isfinite(phi)):
                return None
            e = (z - y).ravel()
            # RLS with forgetting in information form: cov = (lam cov^-1 + phi' phi)^-1, gain = cov phi'
            # (the same as C phi' (lam I + phi C phi')^-1, with a parameters x parameters inverse)
            try:
                cov = np.linalg.inv(lam * np.linalg.inv(C) + phi.T @ phi)
            except np.linalg.LinAlgError:
                return None
            K = cov @ phi.T
            new = np.clip(prior + K @ (e + phi @ (theta - prior)), *BOUNDS)
            moved = float(np.max(np.abs(new - theta)))
            r = e - phi @ (new - theta)
            theta = new
            if moved < ITER_TOL or not far or it == MAX_ITER - 1:
                break
            y, x_end = self._predict(theta, x0, xd0, steps, at)
        return theta, cov, dx, r

    def _remember(self, segment: tuple[np.ndarray, ...]) -> None:
        """Keep every ``_stride``-th whole segment for the session's fit; a long session keeps every
        other one of them, spread over all of it."""
        self._seen += 1
        if self._seen % self._stride == 0:
            self._segments.append(segment)
            if len(self._segments) > SESSION_SEGMENTS:
                del self._segments[::2]
                self._stride *= 2

    def _predict(self, theta: np.ndarray, x0: np.ndarray, xd0: np.ndarray, steps: np.ndarray, at: np.ndarray
                 ) -> tuple[np.ndarray, np.ndarray]:
        """The segment's samples (sensor units) and its end state with the parameters ``theta``."""
        P = self.P.copy()
        self._apply(P, theta)
        x = x0.copy()
        y = self.model.run(steps, x, xd0.copy(), P)[at] / self.model.resolution
        return y, x

    def _sensitivity(self, theta: np.ndarray, x0: np.ndarray, xd0: np.ndarray, steps: np.ndarray, at: np.ndarray,
                     y: np.ndarray, x_end: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """d samples / d theta (samples x parameters) and d end state / d theta at ``theta``, by
        finite differences through the whole segment."""
        phi = np.empty((y.size, theta.size))
        dx = np.empty((x0.size, theta.size))
        for j in range(theta.size):
            th = theta.copy()
            th[j] += NUDGE
            yj, xj = self._predict(th, x0, xd0, steps, at)
            phi[:, j] = (yj - y).ravel() / NUDGE
            dx[:, j] = (xj - x_end) / NUDGE
        return phi, dx

    def estimates(self) -> list[Estimate]:
        """The current values and their 95 % intervals (SI)."""
        sd = np.sqrt(np.maximum(np.diag(self.cov), 0.0) * max(self.sigma2, 1e-12))
        return [Estimate(n, float(v0 * th), float(1.96 * v0 * s), float(v0))
                for n, v0, th, s in zip(self.names, self.nominal, self.theta, sd, strict=True)]



def estimate_report(estimator: InteractionEstimator, history: Sequence[tuple[float, list[Estimate]]],
                    cycle_s: float) -> dict[str, Any]:
    """The estimate per cycle (the running estimate in ``history``, (segment end, estimates), at each
    cycle's end, ``cycle_s`` apart) and per session (``estimator.session_estimates``: least squares over
    every segment since the session began, or since an abrupt change it restarted at; the last running
    value and its interval beside it). ``history`` is not empty."""
    last = history[-1][1]
    cycles: list[dict[str, float]] = []
    k = 1
    for t, ests in history:
        if t + 1e-9 >= k * cycle_s:
            cycles.append({"index": k - 1, "t_end_s": round(t, 4), **{e.name: e.value for e in ests},
                           **{f"{e.name}_ci95": e.ci95 for e in ests}})
            k += 1
    since = estimator.session_start_s
    session = {s.name: {"value": s.value, "ci95": s.ci95, "final": e.value, "final_ci95": e.ci95,
                        "nominal": e.nominal, "since_s": since}
               for s, e in zip(estimator.session_estimates(), last, strict=True)}
    return {"session": session, "cycles": cycles, "cycle_s": cycle_s}
