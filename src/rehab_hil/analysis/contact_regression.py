"""Identify the contact stiffness k and damping c by multiple linear regression (seed 000 eq 30, Table 4).

Seed 000 fits |F| = k |q| + c |q'| with Stata (no intercept: eq 30 has none) on 32 Flexiforce
samples and reports the coefficients, their p-values, and a VIF of 1.05. Here statsmodels' OLS
does the same fit; without a constant Stata and statsmodels both report the *uncentered* R^2. VIF is
given centered (Stata's ``estat vif``, statsmodels' ``variance_inflation_factor``: the paper's 1.05
can only be this one, as both regressors have positive means) and uncentered.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import statsmodels.api as sm
from statsmodels.stats.outliers_influence import variance_inflation_factor

__all__ = ["ContactFit", "describe", "fit_contact"]


@dataclass(frozen=True)
class ContactFit:
    """Regression of force [N] on displacement [mm] and velocity [mm/s] (units of Table 4)."""

    k_n_per_mm: float
    c_n_s_per_mm: float
    se: tuple[float, float]
    t: tuple[float, float]
    p: tuple[float, float]
    r2_uncentered: float
    vif_uncentered: float
    vif_centered: float
    n: int

    def table(self) -> str:
        """Stata-style coefficient table as Markdown."""
        rows = [("displacement (k, N/mm)", self.k_n_per_mm, self.se[0], self.t[0], self.p[0]),
                ("velocity (c, N/(mm/s))", self.c_n_s_per_mm, self.se[1], self.t[1], self.p[1])]
        out = ["| term | coef | std. err. | t | P>|t| |", "|---|---|---|---|---|"]
        out += [f"| {r[0]} | {r[1]:.6g} | {r[2]:.3g} | {r[3]:.2f} | {r[4]:.3g} |" for r in rows]
        out.append(f"\nn = {self.n}, uncentered R^2 = {self.r2_uncentered:.4f}, "
                   f"VIF = {self.vif_uncentered:.2f} (uncentered), {self.vif_centered:.2f} (centered)")
        return "\n".join(out)


def fit_contact(force_n: np.ndarray, displacement_mm: np.ndarray, velocity_mm_s: np.ndarray) -> ContactFit:
    """OLS without intercept of eq 30: force = k displacement + c velocity."""
    y = np.asarray(force_n, float)
    X = np.column_stack([np.asarray(displacement_mm, float), np.asarray(velocity_mm_s, float)])
    if X.shape[0] != y.shape[0] or y.shape[0] < 4:
        raise ValueError("need at least 4 samples of force, displacement and velocity of equal length")
    res = sm.OLS(y, X).fit()
    # two regressors: both VIFs are equal. statsmodels' VIF is the centered one (as Stata's
    # ``estat vif``); the uncentered one regresses x1 on x2 through the origin.
    vif_c = variance_inflation_factor(sm.add_constant(X, has_constant="add"), 1)
    cos2 = float(X[:, 0] @ X[:, 1]) ** 2 / float(X[:, 0] @ X[:, 0]) / float(X[:, 1] @ X[:, 1])
    vif_u = 1.0 / (1.0 - cos2)
    return ContactFit(
        k_n_per_mm=float(res.params[0]), c_n_s_per_mm=float(res.params[1]),
        se=(float(res.bse[0]), float(res.bse[1])), t=(float(res.tvalues[0]), float(res.tvalues[1])),
        p=(float(res.pvalues[0]), float(res.pvalues[1])), r2_uncentered=float(res.rsquared),
        vif_uncentered=float(vif_u), vif_centered=float(vif_c), n=int(y.shape[0]),
    )


def describe(name: str, x: np.ndarray) -> str:
    """One row of Table 4: samples, mean, std. dev. (n - 1), min, max."""
    x = np.asarray(x, float)
    return f"| {name} | {x.size} | {x.mean():.7g} | {x.std(ddof=1):.7g} | {x.min():.5g} | {x.max():.5g} |"
