"""``trial.html``: the cohort's outcomes on one self-contained page (``report/page.py``: plotly inlined).

What a lab asks first: how many patients the controller held at its target, per severity stratum;
then the distributions of the outcomes (empirical CDFs: the share of patients at or below a value),
success against each drawn parameter (where the controller fails), success across sessions, and the
patients it failed, each linked to its run folders.
"""

from __future__ import annotations

import html
import math
from typing import Any

import plotly.graph_objects as go
from plotly.subplots import make_subplots

from rehab_hil.report.page import Page, table
from rehab_hil.trial.results import last_session, meets_target

__all__ = ["trial_page"]

OUTCOMES = (("success_assisted", "success, moves the rig drives"), ("success_last5", "success, last 5 cycles"),
            ("assistance_ratio_last", "assistance ratio, last cycle"), ("peak_temperature_c", "peak temperature [C]"),
            ("active_rom_deg", "active ROM [deg]"), ("sparc", "SPARC"))
COLOURS = ("#1f77b4", "#ff7f0e", "#2ca02c", "#d62728", "#9467bd", "#8c564b")


def _num(v: Any) -> float | None:
    return float(v) if isinstance(v, int | float) and math.isfinite(v) else None


def _strata(patients: list[dict[str, Any]]) -> list[str]:
    return sorted({p["stratum"] for p in patients})


def _ecdf_figure(patients: list[dict[str, Any]], target: float) -> go.Figure:
    """Each outcome's empirical CDF over the patients' last sessions, per stratum and for all."""
    fig = make_subplots(rows=2, cols=3, subplot_titles=[t for _, t in OUTCOMES])
    strata = _strata(patients)
    for i, (key, _) in enumerate(OUTCOMES):
        row, col = i // 3 + 1, i % 3 + 1
        groups = [("all", patients, "#222", 2.5)] + [(s, [p for p in patients if p["stratum"] == s],
                                                     COLOURS[k % len(COLOURS)], 1.2) for k, s in enumerate(strata)]
        for name, group, colour, width in groups:
            v = sorted(x for p in group if (s := last_session(p)) is not None and (x := _num(s.get(key))) is not None)
            if not v:
                continue
            fig.add_trace(go.Scatter(x=v, y=[(j + 1) / len(v) for j in range(len(v))], mode="lines",
                                     line={"shape": "hv", "color": colour, "width": width}, name=name,
                                     legendgroup=name, showlegend=i == 0), row=row, col=col)
        if key.startswith("success"):
            fig.update_xaxes(range=[-0.02, 1.02], row=row, col=col)
            fig.add_trace(go.Scatter(x=[target, target], y=[0, 1], mode="lines", name=f"target {target:g}",
                                     line={"dash": "dot", "color": "crimson"}, legendgroup="target",
                                     showlegend=i == 0), row=row, col=col)
        fig.update_yaxes(title_text="share of patients" if col == 1 else None, range=[0, 1.02], row=row, col=col)
    fig.update_layout(height=620, title="Outcomes of the last session: share of patients at or below a value",
                      margin={"t": 80})
    return fig


def _varied(patients: list[dict[str, Any]]) -> list[str]:
    """The drawn parameters: those whose values differ between patients."""
    keys = sorted({k for p in patients for k in p["parameters"]})
    return [k for k in keys if len({p["parameters"][k] for p in patients if k in p["parameters"]}) > 1]


def _parameter_figure(patients: list[dict[str, Any]], target: float) -> go.Figure | None:
    """Success of the driven moves (last session) against each drawn parameter, coloured by stratum."""
    keys = _varied(patients)
    if not keys:
        return None
    cols = 4
    rows = math.ceil(len(keys) / cols)
    fig = make_subplots(rows=rows, cols=cols, subplot_titles=keys, vertical_spacing=min(0.3 / rows, 0.12))
    strata = _strata(patients)
    for i, key in enumerate(keys):
        row, col = i // cols + 1, i % cols + 1
        xs = [p["parameters"][key] for p in patients if key in p["parameters"]]
        for k, s in enumerate(strata):
            pts = [(p["parameters"][key], _num((last_session(p) or {}).get("success_assisted")), p["id"])
                   for p in patients if p["stratum"] == s and key in p["parameters"]]
            pts = [(x, y, n) for x, y, n in pts if y is not None]
            fig.add_trace(go.Scatter(x=[x for x, _, _ in pts], y=[y for _, y, _ in pts], text=[n for _, _, n in pts],
                                     mode="markers", marker={"color": COLOURS[k % len(COLOURS)], "size": 6},
                                     name=s, legendgroup=s, showlegend=i == 0), row=row, col=col)
        fig.add_trace(go.Scatter(x=[min(xs), max(xs)], y=[target, target], mode="lines", name=f"target {target:g}",
                                 line={"dash": "dot", "color": "crimson"}, legendgroup="target", showlegend=i == 0),
                      row=row, col=col)
        fig.update_yaxes(range=[-0.05, 1.05], row=row, col=col)
    fig.update_layout(height=260 * rows + 80, title="Success of the moves the rig drives against each drawn parameter")
    return fig


def _sessions_figure(patients: list[dict[str, Any]]) -> go.Figure | None:
    """Success of the driven moves session after session: each patient, and the median."""
    most = max((len(p["sessions"]) for p in patients), default=0)
    if most < 2:
        return None
    fig = go.Figure()
    for p in patients:
        fig.add_trace(go.Scatter(x=[s["session"] for s in p["sessions"]],
                                 y=[_num(s.get("success_assisted")) for s in p["sessions"]], mode="lines",
                                 line={"color": "rgba(100,100,100,0.3)", "width": 1}, name=p["id"], showlegend=False))
    med = []
    for k in range(most):
        v = sorted(x for p in patients if len(p["sessions"]) > k
                   and (x := _num(p["sessions"][k].get("success_assisted"))) is not None)
        med.append(v[len(v) // 2] if v else None)
    fig.add_trace(go.Scatter(x=list(range(1, most + 1)), y=med, mode="lines+markers", name="median",
                             line={"color": "#222", "width": 3}))
    fig.update_layout(height=380, title="Success of the moves the rig drives per session",
                      xaxis_title="session", yaxis_title="success", yaxis_range=[-0.05, 1.05])
    return fig


def _links(p: dict[str, Any]) -> str:
    """Links to the patient's profile and each session's run folder (relative to trial.html)."""
    parts = [f'<a href="{html.escape(p["folder"])}/patient.toml">profile</a>']
    parts += [f'<a href="{html.escape(s["run_dir"])}/">session {s["session"]}</a>' for s in p["sessions"]
              if s.get("run_dir")]
    return " ".join(parts)


def _patient_rows(patients: list[dict[str, Any]], target: float) -> str:
    """One row per patient: its outcome, and links."""
    def f(v: Any, digits: int = 3) -> str:
        x = _num(v)
        return "–" if x is None else f"{x:.{digits}g}"

    rows = []
    for p in patients:
        s = last_session(p) or {}
        events = sum(len(x["safety_events"]) for x in p["sessions"])
        err = p.get("error") or {}
        why = f"{err.get('type')}: {err.get('message')}" if err else (
            "; ".join(e["reason"] for x in p["sessions"] for e in x["safety_events"])
            or ("below the target" if not meets_target(p, target) else ""))
        cells = [p["id"], p["stratum"], f(s.get("success_assisted")), f(s.get("success_last5")), f(s.get("success")),
                 f"{f(s.get('assistance_ratio_first'))} → {f(s.get('assistance_ratio_last'))}",
                 f(s.get("peak_temperature_c"), 4), str(events), why]
        rows.append("<tr>" + "".join(f'<td class="l">{html.escape(c)}</td>' if i in (0, 1, 8) else
                                     f"<td>{html.escape(c)}</td>" for i, c in enumerate(cells))
                    + f'<td class="l">{_links(p)}</td></tr>')
    head = ["patient", "stratum", "success (driven)", "last 5", "success (both)", "assistance first → last",
            "peak temperature [C]", "safety events", "why", "run folders"]
    return ("<table><thead><tr>" + "".join(f"<th>{html.escape(h)}</th>" for h in head) + "</tr></thead><tbody>"
            + "".join(rows) + "</tbody></table>")


def trial_page(doc: dict[str, Any]) -> Page:
    """The page of a trial's document (``trial.json``)."""
    t, summ, patients = doc["trial"], doc["summary"], doc["patients"]
    target = summ["target_success"]
    page = Page(f"rehab-hil trial: {t['controller']} on {t['config']}")
    page.text(f"cohort {t['cohort_id']} ({t['cohort']}): {t['patients_finished']} of {t['patients']} patients x "
              f"{t['sessions']} session(s) x {t['duration_s']:g} s, seed {t['seed']}, {t['backend']}, "
              f"{t['wall_s']:.0f} s" + (" — INTERRUPTED: the patients that had finished" if t["interrupted"] else ""),
              cls="sub")
    page.heading("Outcome")
    page.text(f"A patient meets the target when every session ran with no safety event and the last session's "
              f"moves the rig drives succeeded at {target:.0%} or more.")
    groups = [("all", summ), *summ["strata"].items()]
    page.raw(table(["patients", "n", "met the target", "share", "errors", "with safety events",
                    "median success (driven)", "median last 5", "median assistance ratio (last cycle)",
                    "hottest [C]"],
                   [[name, g["patients"], g["met"], g["met_share"], g["errors"], g["with_safety_events"],
                     g["median_success_assisted"], g["median_success_last5"], g["median_assistance_ratio_last"],
                     g["max_peak_temperature_c"]] for name, g in groups]))
    if patients:
        page.figure(_ecdf_figure(patients, target))
        for fig in (_parameter_figure(patients, target), _sessions_figure(patients)):
            if fig is not None:
                page.figure(fig)
    failed = [p for p in patients if not meets_target(p, target)]
    page.heading(f"The patients the controller failed ({len(failed)})")
    page.raw(_patient_rows(failed, target) if failed else "<p>none</p>")
    page.heading(f"Every patient ({len(patients)})")
    page.raw(_patient_rows(patients, target))
    return page
