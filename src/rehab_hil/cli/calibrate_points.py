"""``rehab-hil calibrate force --points CSV``: refit published static calibration points offline
(no device): per sensor the chosen fit and the residual of each candidate beside the published
linear fit (``rehab_hil.analysis.flexiforce``)."""

from __future__ import annotations

from pathlib import Path

from rich.console import Console
from rich.table import Table

from rehab_hil.analysis.flexiforce import fit_static, read_points

__all__ = ["run_points"]


def run_points(path: Path, console: Console | None = None) -> int:
    console = console or Console()
    t = Table(title=f"static calibration of {path}: force [N] from raw counts")
    for col in ("sensor", "points", "chosen", "coefficients (c0, c1, ...)", "RMS linear [N]", "RMS quadratic [N]",
                "RMS published linear [N]"):
        t.add_column(col)
    for sensor, (load, counts) in read_points(path).items():
        fit = fit_static(sensor, load, counts)
        pub = "-" if fit.published_rms_n is None else f"{fit.published_rms_n:.3f}"
        t.add_row(sensor, str(fit.n_points), fit.model, ", ".join(f"{c:.6g}" for c in fit.coefficients),
                  f"{fit.rms_n['linear']:.3f}", f"{fit.rms_n['quadratic']:.3f}", pub)
    t.caption = "chosen by AICc; published: Dickmann et al. 2021 (F_A = 0.0036 ADC - 2.0806, F_B = 0.0033 ADC - 2.2402)"
    console.print(t)
    return 0
