"""Online estimate of the patient's interaction parameters: recursive least squares with forgetting
on the model's own prediction error (a recursive prediction-error method, Ljung & Soderstrom 1983).

Seed 000 identifies the human-machine contact's stiffness k and damping c (Table 4, eq 30) offline,
by multiple linear regression of the measured contact force on the pad's deformation and its rate.
Online, on a rig that measures an angle (and maybe a force), the same parameters are those of the
model's torque balance: the twin's model with the estimated values is run over each re-anchored
segment, and once more per parameter with that parameter nudged, which gives the sensitivity of
every predicted sample to every parameter (finite differences through the whole plant: contact,
passive joint, actuator and controller-applied effort alike). The segment's prediction error then
updates the estimate by RLS with exponential forgetting (memory ``forgetting_s``), so a patient
whose stiffness doubles is followed within a few memories. Parameters are estimated relative to
their config value (1 = the config), which keeps the problem well scaled; the 95 % interval comes
from the RLS covariance times the residual variance.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from rehab_hil.discrepancy.replay import CANDIDATE_PREFIX
from rehab_hil.twin.model import TwinModel, TwinSetupError

__all__ = ["Estimate", "InteractionEstimator", "default_estimates", "resolve_parameters"]

NUDGE = 0.05  # finite-difference step: this share of the parameter's config value
SUBSAMPLE = 5  # every this many samples of a segment enter the regression (neighbours are correlated)
P0 = 1.0  # initial covariance of the relative parameters (a prior of +/-100 %)
BOUNDS = (0.02, 20.0)  # the estimate stays within these multiples of the config value
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
    effect's ``effect.param``; every other non-candidate part's parameter of the same name and value
    goes with it (the SMA's pad and contact-force parts share k and c). Unknown names are refused."""
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
        idx = [i0] + [i for i, q in enumerate(names_all) if i != i0 and q.split(".", 1)[1] == param
                      and not q.startswith(CANDIDATE_PREFIX) and model.P[i] == v0]
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
        self._apply(self.P, self.theta)

    def _apply(self, P: np.ndarray, theta: np.ndarray) -> None:
        for ix, v0, th in zip(self.index, self.nominal, theta, strict=True):
            P[ix] = v0 * th

    def update(self, index: np.ndarray, U: np.ndarray, measured: np.ndarray) -> None:
        """One segment of samples (as ``TwinModel.advance`` takes them): predict it with the current
        estimate from the estimator's own re-anchored state, and update the estimate."""
        m = self.model
        if not m.anchored:
            m.advance(index, U, measured)
            return
        x0, xd0 = m.x.copy(), m.xd.copy()
        steps, at = m.plan(index, U)
        y_hat_all = m.advance(index, U, measured).predicted
        keep = np.arange(0, at.size, SUBSAMPLE)
        if keep.size < 2 or not np.all(np.isfinite(measured[keep])):
            return
        scale = m.resolution
        y_hat = y_hat_all[keep]
        e = ((measured[keep] - y_hat) / scale).ravel()
        phi = np.empty((e.size, self.theta.size))
        for j in range(self.theta.size):
            th = self.theta.copy()
            th[j] += NUDGE
            Pj = self.P.copy()
            self._apply(Pj, th)
            phi[:, j] = ((self._run(Pj, x0, xd0, steps)[at[keep]] - y_hat) / scale).ravel() / NUDGE
        if not np.all(np.isfinite(phi)) or not np.all(np.isfinite(e)):
            return
        lam, C = self.lam, self.cov
        S = lam * np.eye(e.size) + phi @ C @ phi.T
        try:
            K = np.linalg.solve(S, phi @ C).T
        except np.linalg.LinAlgError:
            return
        self.theta = np.clip(self.theta + K @ e, *BOUNDS)
        self.cov = (C - K @ phi @ C) / lam
        self.cov = 0.5 * (self.cov + self.cov.T)
        r = e - phi @ (K @ e)
        self.sigma2 = lam * self.sigma2 + (1 - lam) * float(np.mean(r**2)) if self.updates else float(np.mean(r**2))
        self.updates += 1
        self._apply(self.P, self.theta)

    def _run(self, P: np.ndarray, x0: np.ndarray, xd0: np.ndarray, steps: np.ndarray) -> np.ndarray:
        return self.model.run(steps, x0.copy(), xd0.copy(), P)

    def estimates(self) -> list[Estimate]:
        """The current values and their 95 % intervals (SI)."""
        sd = np.sqrt(np.maximum(np.diag(self.cov), 0.0) * max(self.sigma2, 1e-12))
        return [Estimate(n, float(v0 * th), float(1.96 * v0 * s), float(v0))
                for n, v0, th, s in zip(self.names, self.nominal, self.theta, sd, strict=True)]
