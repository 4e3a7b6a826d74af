"""The discrepancy workflow's result as the same kind of HTML page as the session report
(``report.html`` beside report.md): measured against the nominal and the augmented model per
channel with the held-out part shaded, the residual before and after, the effects chosen and the
RMSE per channel."""

from __future__ import annotations

from typing import Any

import numpy as np
import plotly.graph_objects as go
from plotly.subplots import make_subplots

from rehab_hil.report.figures import SESSION_BUCKETS, envelope
from rehab_hil.report.page import Page, table

__all__ = ["discrepancy_page"]


def _line(t: np.ndarray, y: np.ndarray, name: str, **kw: Any) -> go.Scatter:
    tt, yy = envelope(t, y, SESSION_BUCKETS)
    return go.Scatter(x=tt.astype(np.float32), y=yy.astype(np.float32), name=name, mode="lines", **kw)


def _overlay(res: Any, residual: bool) -> go.Figure:
    n = len(res.channels)
    fig = make_subplots(rows=n, cols=1, shared_xaxes=True, vertical_spacing=0.06, subplot_titles=res.channels)
    aug = "augmented" + (f" (+{', '.join(res.named)})" if res.named else "")
    for i, c in enumerate(res.channels, start=1):
        first = i == 1
        if residual:
            fig.add_trace(_line(res.t, res.nominal[c] - res.measured[c], "residual, nominal", showlegend=first,
                                line={"color": "#1f77b4", "width": 1}), row=i, col=1)
            fig.add_trace(_line(res.t, res.augmented[c] - res.measured[c], "residual, " + aug, showlegend=first,
                                line={"color": "#d62728", "width": 1}), row=i, col=1)
        else:
            fig.add_trace(_line(res.t, res.measured[c], "measured", showlegend=first,
                                line={"color": "black", "width": 1}), row=i, col=1)
            fig.add_trace(_line(res.t, res.nominal[c], "nominal", showlegend=first,
                                line={"color": "#1f77b4", "width": 1}), row=i, col=1)
            fig.add_trace(_line(res.t, res.augmented[c], aug, showlegend=first,
                                line={"color": "#d62728", "width": 1, "dash": "dash"}), row=i, col=1)
        fig.add_vrect(x0=res.split_s, x1=float(res.t[-1]), fillcolor="#999", opacity=0.15, line_width=0, row=i, col=1)
    fig.update_xaxes(title_text="time [s] (shaded: held out from the fit)", row=n, col=1)
    fig.update_layout(template="plotly_white", height=240 * n + 100, hovermode="x unified",
                      margin={"l": 60, "r": 20, "t": 70, "b": 40}, legend={"orientation": "h", "y": -0.1},
                      title="Residual (model - measured)" if residual else "Measured and model")
    return fig


def _g(v: Any, digits: int) -> str:
    return f"{v:.{digits}g}" if isinstance(v, int | float) else "–"


def discrepancy_page(res: Any, rep: dict[str, Any]) -> Page:
    """The page for a ``discrepancy.result.Result`` and its ``report_dict``."""
    page = Page(f"rehab-hil discrepancy: {rep['plant']}")
    page.text(f"config {rep['config']}, data {rep['data']}: {rep['samples']} samples over "
              f"{rep['duration_s']:.1f} s, held out from {rep['holdout_start_s']:.1f} s", cls="sub")
    page.heading("Conclusion")
    page.text(str(rep["conclusion"]))
    chosen = rep.get("chosen") or []
    if chosen:
        page.raw(table(["effect", "kind", "parameters"],
                       [[c["effect"], c["kind"], ", ".join(f"{k} = {_g(v, 4)} ± {_g((c.get('stderr') or {}).get(k), 2)}"
                                                           for k, v in c["params"].items())] for c in chosen],
                       left=3))
    m = rep["metrics"]
    page.raw(table(["channel", "RMSE nominal", "RMSE augmented", "held-out RMSE nominal",
                    "held-out RMSE augmented", "gap closed [%]"],
                   [[c, m["nominal"][c]["rmse"], m["augmented"][c]["rmse"], m["nominal_holdout"][c]["rmse"],
                     m["augmented_holdout"][c]["rmse"], rep["gap_reduction_pct"].get(c)] for c in rep["channels"]]))
    for a in rep.get("aliases") or []:
        page.note(a["sentence"])
    page.figure(_overlay(res, residual=False))
    page.figure(_overlay(res, residual=True))
    return page
