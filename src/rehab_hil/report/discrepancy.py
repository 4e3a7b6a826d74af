"""The discrepancy workflow's result as the same kind of HTML page as the session report
(``report.html`` beside report.md), holding everything report.md holds: the conclusion, the terms
chosen with their units, the residual beside the noise floor, the RMSE per channel, the replay mode
and start state, the validation, the joint identification and every round's candidate ranking;
measured against the nominal and the augmented model per channel (held-out part shaded) and the
residual before and after, each axis with its unit."""

from __future__ import annotations

from typing import Any

import numpy as np
import plotly.graph_objects as go
from plotly.subplots import make_subplots

from rehab_hil.discrepancy.report import effect_params_text
from rehab_hil.discrepancy.verdict import channel_unit
from rehab_hil.discrepancy.wording import change_words
from rehab_hil.report.figures import SESSION_BUCKETS, envelope
from rehab_hil.report.page import Page, table

__all__ = ["discrepancy_page"]


def _line(t: np.ndarray, y: np.ndarray, name: str, **kw: Any) -> go.Scatter:
    tt, yy = envelope(t, y, SESSION_BUCKETS)
    return go.Scatter(x=tt.astype(np.float32), y=yy.astype(np.float32), name=name, mode="lines", **kw)


def _overlay(res: Any, residual: bool) -> go.Figure:
    n = len(res.channels)
    titles = [f"{c} [{channel_unit(c)}]" if channel_unit(c) else c for c in res.channels]
    fig = make_subplots(rows=n, cols=1, shared_xaxes=True, vertical_spacing=0.06, subplot_titles=titles)
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
        unit = channel_unit(c)
        fig.update_yaxes(title_text=(f"model - measured [{unit}]" if residual else f"{c} [{unit}]") if unit
                         else c, row=i, col=1)
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
        page.raw(table(["term", "kind", "fitted"],
                       [[c["effect"], c["kind"], c.get("sentence") or effect_params_text(c)
                         + (f" ({c['description']}; {c['seed']})" if c.get("description") else "")]
                        for c in chosen], left=3))
    for r in (rep.get("held_out_judgement") or {}).get("rejected", []):
        page.note(f"Not a finding: {r['sentence']} (augmented.toml keeps the given value).")
    for a in rep.get("aliases") or []:
        page.note(a["sentence"])
    _metrics(page, rep)
    if rep.get("held_out_judgement"):
        page.text(f"Findings {rep['held_out_judgement']['summary']} (a term that makes these data worse than its "
                  "given value is rejected, not a finding).")
    _replay(page, rep)
    _validation(page, rep.get("validation"))
    _joint(page, rep.get("joint_identification"))
    _rounds(page, rep)
    page.figure(_overlay(res, residual=False))
    page.figure(_overlay(res, residual=True))
    return page


def _metrics(page: Page, rep: dict[str, Any]) -> None:
    m, units, resid = rep["metrics"], rep.get("channel_units") or {}, rep.get("residual") or {}
    page.heading("Error per channel")
    page.text(f"Both models measured the same way ({rep['replay'].get('measure', '')}; a validation record is "
              "a whole-record open-loop replay); the held-out residual of the final model beside the noise floor "
              "the data show.")
    page.raw(table(["channel", "unit", "RMSE nominal", "RMSE augmented", "held-out RMSE nominal",
                    "held-out RMSE augmented", "error", "noise floor", "residual / spread [%]"],
                   [[c, units.get(c, ""), m["nominal"][c]["rmse"], m["augmented"][c]["rmse"],
                     m["nominal_holdout"][c]["rmse"], m["augmented_holdout"][c]["rmse"],
                     change_words(rep["gap_reduction_pct"][c]), (resid.get(c) or {}).get("noise_floor"),
                     100 * float((resid.get(c) or {}).get("share_of_spread") or float("nan"))]
                    for c in rep["channels"]], left=2))


def _replay(page: Page, rep: dict[str, Any]) -> None:
    r, init = rep["replay"], rep.get("initial_state") or {}
    page.heading("Replay and start state")
    seg = f", {r['segment_s']:g} s segments" if r.get("segment_s") else ""
    page.text(f"Mode: {r['mode']}{seg} (nominal model, fit part, scaled RMS: open loop "
              f"{_g(r.get('open_rms'), 3)}, shooting {_g(r.get('shooting_rms'), 3)}). {r['loop']}.")
    page.text("Start state: " + ("; ".join(init.get("summary") or []) or "the config's rest state") + ".")


def _validation(page: Page, val: dict[str, Any] | None) -> None:
    if not val:
        return
    page.heading(f"Validation on {val['data']}")
    page.text(f"Replay: {val['replay']}.")
    page.raw(table(["channel", "RMSE nominal", "RMSE augmented", "error"],
                   [[c, val["metrics"]["nominal"][c]["rmse"], val["metrics"]["augmented"][c]["rmse"],
                     change_words(val["error_cut_pct"][c])] for c in val["channels"]]))


def _joint(page: Page, joint: dict[str, Any] | None) -> None:
    if not joint or not joint.get("parameters"):
        return
    page.heading("Joint identification (every parameter fitted together)")
    page.raw(table(["parameter", "value", "unit", "95 % CI", "note"],
                   [[p["name"], p["value"], p.get("unit", ""),
                     "–" if p["ci95"] is None else f"{p['ci95'][0]:.4g} .. {p['ci95'][1]:.4g}",
                     "held at its config value (inseparable)" if p["held_at_config"] else ""]
                    for p in joint["parameters"]], left=1))
    for s in joint.get("sentences") or []:
        page.note(s)


def _rounds(page: Page, rep: dict[str, Any]) -> None:
    for i, rd in enumerate(rep.get("rounds") or [], 1):
        page.heading(f"Round {i}: candidates (held-out BIC, best first)" + (f"; chosen {rd['chosen']}"
                                                                            if rd.get("chosen") else ""))
        page.raw(table(["term", "parameters", "ΔBIC", "best channel cut [%]", "significant"],
                       [[c["effect"], effect_params_text({"params": c["params"], "units": c.get("units")}),
                         c["delta_bic"],
                         100 * c["improvement"], "yes" if c["significant"] else "no"] for c in rd["candidates"]],
                       left=2))
