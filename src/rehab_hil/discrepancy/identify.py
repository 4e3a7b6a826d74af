"""Every nominal parameter fitted together, and what the record can and cannot separate.

After the search (``workflow``), the plant's declared parameters (``Plant.fit_parameters``, the
coupled groups among them: a weaker magnet lowers the torque constant and the back-EMF constant
together) and the chosen effects are refitted jointly on the fit part. The Jacobian of the scaled
residual at that optimum (central differences) gives the covariance s^2 (J^T J)^-1 (inflated for
correlated residuals, ``selection.effective_fraction``) and so the parameter correlations; its
singular values, with the columns normalised, say which combinations the record pins down
(identifiability from the sensitivity matrix: Brun, Reichert and Kuensch 2001, collinearity index;
Raue et al. 2009 use profile likelihoods for the same question). A direction whose singular value is
below ``COLLINEAR`` of the largest is a combination the record cannot see: its members with a weight of
at least ``MEMBER_WEIGHT`` form an inseparable group, reported with every name and no interval of its
own. To give the others values, the group's declared parameters are held at their config values,
last declared first (a plant declares the parameters it knows best last: a drive gain measured on
a bench), until no such direction is left, and the rest is refitted. Of declared parameters that
share a model parameter (k_t alone and the flux group) only the first not already chosen takes part.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from rehab_hil.discrepancy.bounds import on_bound
from rehab_hil.discrepancy.fitting import DIFF_STEP, Fit, Term, fit_joint, parameter_term
from rehab_hil.discrepancy.parameters import ERROR_PARAM, config_value, parameter_terms
from rehab_hil.discrepancy.replay import Replay
from rehab_hil.discrepancy.selection import effective_fraction

__all__ = ["COLLINEAR", "MEMBER_WEIGHT", "JointIdentification", "identify_jointly"]

COLLINEAR = 0.05  # sigma_min / sigma_max of the normalised sensitivities: two columns correlated beyond 0.9987
MEMBER_WEIGHT = 0.25  # a parameter belongs to an unseen combination when its weight in the direction is this large
Z95 = 1.959964


@dataclass
class JointIdentification:
    """The joint fit: values (SI; a parameter's relative error and its corrected value), standard
    errors, correlations, inseparable groups and the parameters held at their config values."""

    names: list[str]  # "<term>.<param>" in fit order
    values: dict[str, float]
    stderr: dict[str, float]
    correlation: np.ndarray
    inseparable: list[list[str]] = field(default_factory=list)
    held: dict[str, list[str]] = field(default_factory=dict)  # held parameter -> the group it could not leave
    corrected: dict[str, float] = field(default_factory=dict)  # parameter config key -> value after the fit
    n_simulations: int = 0
    at_bound: dict[str, tuple[Any, float, str]] = field(default_factory=dict)  # label -> (param, value, side)

    def sentences(self) -> list[str]:
        """One per inseparable group: every name, and what was done about it."""
        out = []
        for g in self.inseparable:
            held = [h for h in self.held if h in g]
            rest = [m for m in g if m not in held]
            tail = (f": {', '.join(held)} held at its config value, {', '.join(rest)} fitted relative to it" if held
                    else ": no interval is given for them alone")
            out.append(f"{' and '.join(g)} are not separable from this record (only their combination is "
                       f"identified){tail}")
        return out

    def as_dict(self) -> dict[str, Any]:
        names = self.names
        return {"parameters": [{"name": n, "value": self.values[n], "stderr": self.stderr.get(n),
                                "ci95": ([self.values[n] - Z95 * self.stderr[n], self.values[n] + Z95 * self.stderr[n]]
                                         if np.isfinite(self.stderr.get(n, np.nan)) else None),
                                "held_at_config": n in self.held} for n in names],
                "corrected": self.corrected, "inseparable": self.inseparable,
                "held": self.held, "at_bound": sorted(self.at_bound),
                "correlation": {"names": names, "matrix": np.round(self.correlation, 4).tolist()},
                "sentences": self.sentences(), "n_simulations": self.n_simulations}


def _label(term: Term, p: str) -> str:
    return term.name if term.kind == "parameter" else f"{term.name}.{p}"


def _jacobian(replay: Replay, P0: np.ndarray, terms: Sequence[Term], fits: Sequence[Fit],
              n_train: int) -> tuple[np.ndarray, np.ndarray, list[str], np.ndarray]:
    """Scaled residual Jacobian (central differences of DIFF_STEP typical values), residual, labels, typicals."""
    layout = [(t, p) for t in terms for p in t.params]
    typ = np.array([p.typical for _, p in layout])
    vals = np.array([f.params[p.name] for f in fits for p in next(t for t in terms if t.name == f.effect).params])

    def residual(v: np.ndarray) -> np.ndarray:
        P, k = P0, 0
        for t in terms:
            P = t.apply(P, {p.name: float(v[k + j]) for j, p in enumerate(t.params)})
            k += len(t.params)
        sim = replay.simulate(P, n_train, sensed=False)
        return replay.residual(sim, slice(replay.fit_start, n_train), weighted=True).ravel()

    r0 = residual(vals)
    J = np.empty((r0.size, vals.size))
    for i in range(vals.size):
        h = DIFF_STEP * typ[i]
        up, dn = vals.copy(), vals.copy()
        up[i] += h
        dn[i] -= h
        J[:, i] = (residual(up) - residual(dn)) / (2.0 * h / typ[i])  # per typical value
    return J, r0, [_label(t, p.name) for t, p in layout], typ


def _weak_direction(J: np.ndarray) -> np.ndarray | None:
    """The least-seen direction of the normalised sensitivities if the record cannot see it, else None."""
    norms = np.linalg.norm(J, axis=0)
    if np.any(norms == 0.0):
        v = np.zeros(J.shape[1])
        v[int(np.argmin(norms))] = 1.0
        return v
    _, s, vt = np.linalg.svd(J / norms, full_matrices=False)
    return vt[-1] if s[-1] < COLLINEAR * s[0] else None


def identify_jointly(replay: Replay, P0: np.ndarray, chosen_terms: Sequence[Term], chosen: Sequence[Fit],
                     n_train: int, tick: Callable[[], None] | None = None) -> JointIdentification:
    """Fit the chosen terms and every declared parameter (nominal value not zero) together; check
    what the record separates; hold inseparable declared parameters at their config values."""
    terms: list[Term] = [*chosen_terms, *_declared_terms(replay, chosen_terms)]
    starts = [dict(f.params) for f in chosen] + [{ERROR_PARAM.name: 0.0} for t in terms[len(chosen_terms):]]
    held: dict[str, list[str]] = {}
    groups: list[list[str]] = []
    count = 0
    while True:
        fits = fit_joint(replay, P0, terms, starts, n_train, tick)
        count += fits[0].n_simulations if fits else 0
        if not terms:
            return JointIdentification([], {}, {}, np.zeros((0, 0)), n_simulations=count)
        J, r0, labels, typ = _jacobian(replay, P0, terms, fits, n_train)
        count += 2 * len(labels) + 1
        drop = _hold_one(J, labels, terms[len(chosen_terms):], held, groups)
        if drop is None:
            break
        i = terms.index(drop)
        terms, starts = terms[:i] + terms[i + 1:], starts[:i] + starts[i + 1:]
    sd, corr = _uncertainty(replay, J, r0, typ)
    values = {lab: f.params[p.name] for f, t in zip(fits, terms, strict=True) for p in t.params
              for lab in [_label(t, p.name)]}
    stderr = dict(zip(labels, sd.tolist(), strict=True))
    for g in groups:  # a group nothing could be held in (only chosen effects): no interval of their own
        if not any(h in g for h in held):
            for m in g:
                stderr[m] = float("nan")
    for h in held:
        values[h] = 0.0
        stderr[h] = float("nan")
    names = [*labels, *held]
    full = np.full((len(names), len(names)), np.nan)
    full[:len(labels), :len(labels)] = corr
    bound = {_label(t, p.name): (p, f.params[p.name], side) for f, t in zip(fits, terms, strict=True)
             for p in t.params for side in [on_bound(p, f.params[p.name])] if side}
    return JointIdentification(names, values, stderr, full, groups, held, _corrected(replay, terms, values, held),
                               count, bound)


def _declared_terms(replay: Replay, chosen_terms: Sequence[Term]) -> list[Term]:
    """The declared parameters not chosen, with a nominal value, sharing no model parameter with one
    already in (k_t alone and the flux group: the first not already chosen takes part)."""
    have = {t.name for t in chosen_terms}
    pts = parameter_terms(replay)
    used = {i for p in pts if p.name in have for i in p.indices}
    declared: list[Term] = []
    for p in pts:
        if p.name in have or not any(v != 0.0 for v in p.nominal) or used & set(p.indices):
            continue
        used |= set(p.indices)
        declared.append(parameter_term(p))
    return declared


def _hold_one(J: np.ndarray, labels: Sequence[str], declared: Sequence[Term], held: dict[str, list[str]],
              groups: list[list[str]]) -> Term | None:
    """The declared parameter to hold at its config value next, or None when the record sees every
    direction (or only chosen terms are collinear); records the inseparable group in ``groups`` and
    the held parameter in ``held``."""
    weak = _weak_direction(J)
    if weak is None:
        return None
    members = [labels[i] for i in np.flatnonzero(np.abs(weak) >= MEMBER_WEIGHT * np.abs(weak).max())]
    # hold the last declared parameter of the group (not a chosen term: the search's own story stays)
    free = [t for t in declared if t.name in members]
    if not free:  # only chosen terms are collinear (an exponential's scale and shape): said, no intervals
        groups.append(sorted(members))
        return None
    merged = {*members, *[m for g in groups if set(g) & set(members) for m in g]}
    groups[:] = [g for g in groups if not set(g) & set(members)] + [sorted(merged)]
    held[free[-1].name] = members
    return free[-1]


def _uncertainty(replay: Replay, J: np.ndarray, r0: np.ndarray, typ: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Standard errors (SI) and correlations from the Jacobian, inflated for correlated residuals."""
    n, k = r0.size, J.shape[1]
    s2 = float(r0 @ r0) / max(n - k, 1)
    frac = effective_fraction(r0.reshape(len(replay.channels), -1))
    cov = np.linalg.pinv(J.T @ J) * s2 / frac * np.outer(typ, typ)
    sd = np.sqrt(np.clip(np.diag(cov), 0.0, None))
    return sd, cov / np.where(np.outer(sd, sd) > 0, np.outer(sd, sd), 1.0)


def _corrected(replay: Replay, terms: Sequence[Term], values: dict[str, float],
               held: dict[str, list[str]]) -> dict[str, float]:
    """Config key -> value after the fit: a fitted parameter's corrected, a held one's as configured."""
    corrected = {}
    fps = {fp.name: fp for fp in replay.spec.fit_parameters}
    for t in terms:
        if t.kind == "parameter":
            fp = fps[t.name]
            for key in (fp.config_key, *fp.also):
                corrected[key] = config_value(replay.cfg, key) * (1.0 + values[t.name])
    for h in held:
        for key in (fps[h].config_key, *fps[h].also):
            corrected[key] = config_value(replay.cfg, key)
    return corrected
