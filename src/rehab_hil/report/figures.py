"""The report's plotly figures. Long records are drawn through a min/max envelope: every bucket of
samples keeps its lowest and highest point in time order, so a 10 min 1 kHz session is a few
thousand points per trace and no peak (a force spike, a trip) is lost."""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

import numpy as np
import plotly.graph_objects as go
from plotly.subplots import make_subplots

from rehab_hil.report.names import label, quantity, unit
from rehab_hil.report.runs import RunData

__all__ = ["SESSION_BUCKETS", "cycle_figure", "cycle_trend_figure", "envelope", "progress_figure",
           "session_figure", "trend_keys"]

SESSION_BUCKETS = 1500  # min/max buckets per trace over the whole session (3000 points)
CYCLE_BUCKETS = 150  # per cycle in the overlay

_LAYOUT = {"template": "plotly_white", "margin": {"l": 60, "r": 20, "t": 70, "b": 40},
           "legend": {"orientation": "h", "y": -0.08}, "hovermode": "x unified"}


def envelope(t: np.ndarray, y: np.ndarray, buckets: int) -> tuple[np.ndarray, np.ndarray]:
    """At most ``2 * buckets`` points of (t, y): each bucket's min and max, in time order; NaN kept
    out of them, and a bucket with no number one NaN point (the line breaks there)."""
    t, y = np.asarray(t, float), np.asarray(y, float)
    if t.size <= 2 * buckets:
        return t, y
    edges = np.linspace(0, t.size, buckets + 1).astype(int)
    starts = edges[:-1]
    yy = np.where(np.isfinite(y), y, np.nan)
    # argmin / argmax per bucket with reduceat on finite data
    filled_lo = np.where(np.isnan(yy), np.inf, yy)
    filled_hi = np.where(np.isnan(yy), -np.inf, yy)
    mins = np.minimum.reduceat(filled_lo, starts)
    maxs = np.maximum.reduceat(filled_hi, starts)
    idx = []
    for b, (s, e) in enumerate(zip(starts, edges[1:], strict=True)):
        seg_lo, seg_hi = filled_lo[s:e], filled_hi[s:e]
        if not np.isfinite(mins[b]):  # nothing here (no reference after the stop): a gap, not a line across
            idx.append(s)
            continue
        i, j = s + int(np.argmax(seg_lo == mins[b])), s + int(np.argmax(seg_hi == maxs[b]))
        idx.extend((i, j) if i <= j else (j, i))
    k = np.unique(np.asarray(idx, int))
    return t[k], y[k]


def _f32(a: np.ndarray) -> np.ndarray:
    return np.asarray(a, np.float32)


def _line(t: np.ndarray, y: np.ndarray, name: str, buckets: int, **kw: Any) -> go.Scatter:
    tt, yy = envelope(t, y, buckets)
    return go.Scatter(x=_f32(tt), y=_f32(yy), name=name, mode="lines", **kw)


def _event_shapes(fig: go.Figure, events: Sequence[dict[str, Any]], rows: int, color: str = "crimson") -> None:
    for ev in events:
        t = ev.get("t_s")
        if not isinstance(t, int | float) or not math.isfinite(t):
            continue
        fig.add_vline(x=t, line={"color": color, "dash": "dot", "width": 1.5}, row="all", col=1)
        fig.add_annotation(x=t, y=1.0, yref="paper", text=str(ev.get("reason", "event")), showarrow=False,
                           font={"color": color, "size": 11}, xanchor="left", yanchor="bottom",
                           hovertext=str(ev.get("detail", "")))


def session_figure(run: RunData, buckets: int = SESSION_BUCKETS) -> go.Figure:
    """The whole session on one time axis: angle and reference, each sensor that varies (force,
    torque: its own name and unit), temperature, duty, events. Rows with no reference (before the
    first command, after the stop) leave a gap in the reference, not a drop to 0."""
    rows = [(label(run.angle_name), "angle"), *((label(n), n) for n in run.sensors)]
    if run.temperature is not None:
        rows.append((label("estimated_temperature_c"), "temperature"))
    if run.duty:
        rows.append(("applied duty [0-1]", "duty"))
    fig = make_subplots(rows=len(rows), cols=1, shared_xaxes=True, vertical_spacing=0.04,
                        subplot_titles=[r[0] for r in rows])
    row = {key: i + 1 for i, (_, key) in enumerate(rows)}
    t = run.t
    fig.add_trace(_line(t, run.reference, "reference", buckets, line={"color": "#888", "dash": "dash"}), row=1, col=1)
    fig.add_trace(_line(t, run.angle, quantity(run.angle_name), buckets, line={"color": "#1f77b4"}), row=1, col=1)
    for name, y in run.sensors.items():
        fig.add_trace(_line(t, y, quantity(name), buckets), row=row[name], col=1)
    if run.temperature is not None:
        fig.add_trace(_line(t, run.temperature, quantity("estimated_temperature_c"), buckets,
                            line={"color": "#d62728"}), row=row["temperature"], col=1)
    for name, y in run.duty.items():
        fig.add_trace(_line(t, y, quantity(name), buckets, line={"shape": "hv"}), row=row["duty"], col=1)
    for i, (text, _) in enumerate(rows):
        fig.update_yaxes(title_text=text[text.rindex("[") + 1:-1] if text.endswith("]") else "", row=i + 1, col=1)
    _event_shapes(fig, run.events, len(rows))
    _event_shapes(fig, [{"t_s": e.get("t_s"), "reason": "model_mismatch", "detail": e.get("cause", "")}
                        for e in run.meta.get("model_events") or []], len(rows), color="darkorange")
    fig.update_xaxes(title_text="time [s]", row=len(rows), col=1)
    fig.update_layout(**_LAYOUT, height=230 * len(rows) + 80, title="Session")
    return fig


def cycle_figure(run: RunData, buckets: int = CYCLE_BUCKETS) -> go.Figure:
    """Every open-close cycle on one axis (time from the cycle's start), the reference dashed."""
    fig = go.Figure()
    n = len(run.cycles)
    for k, c in enumerate(run.cycles):
        sel = (run.t >= c["start_s"]) & (run.t < c["end_s"])
        if not sel.any():
            continue
        tc = run.t[sel] - c["start_s"]
        if k == 0:
            fig.add_trace(_line(tc, run.reference[sel], "reference", buckets,
                                line={"color": "#444", "dash": "dash", "width": 2}))
        shade = 0.25 + 0.75 * (k + 1) / n
        fig.add_trace(_line(tc, run.angle[sel], f"cycle {int(c['index'])}", buckets,
                            line={"color": f"rgba(31,119,180,{shade:.2f})", "width": 1.2}))
    fig.update_layout(**_LAYOUT, height=380, title="Angle per cycle",
                      xaxis_title="time from cycle start [s]", yaxis_title=label(run.angle_name))
    return fig


def trend_keys(run: RunData) -> list[tuple[str, str, str, float | None, str]]:
    """The per-cycle plots: (key, title, unit, the smallest change the rig can see, what that is)."""
    res = run.angle_resolution_deg
    keys = [("rom_deg", "range of motion", "deg", res, "one encoder count")]
    if run.sensor_name:
        name = run.sensor_name
        keys.append(("peak_force", f"peak {quantity(name)}", unit(name), run.sensor_resolution(name), "one ADC count"))
    return [*keys, ("rmse_deg", "tracking RMSE", "deg", res, "one encoder count"),
            ("energy_j", "electrical energy", "J", None, "")]


def cycle_trend_figure(run: RunData) -> go.Figure:
    """Per-cycle figures against the cycle number, on zero-based axes with whole-cycle ticks: a change
    across cycles smaller than the rig can see (one encoder or ADC count) gets a band one count wide
    around it, so it is not read as a slope."""
    keys = trend_keys(run)
    fig = make_subplots(rows=1, cols=len(keys), subplot_titles=[f"{k[1]} [{k[2]}]" for k in keys],
                        horizontal_spacing=0.07)
    idx = [int(c["index"]) for c in run.cycles]
    step = max(1, math.ceil(len(idx) / 8))
    for i, (k, title, u, resolution, what) in enumerate(keys):
        y = [_num(c.get(k)) for c in run.cycles]
        fig.add_trace(go.Scatter(x=idx, y=y, mode="lines+markers", name=title, showlegend=False), row=1, col=i + 1)
        fig.update_xaxes(title_text="cycle", dtick=step, tick0=idx[0] if idx else 0, row=1, col=i + 1)
        fig.update_yaxes(title_text=u, rangemode="tozero", row=1, col=i + 1)
        vals = [v for v in y if v is not None]
        if resolution and len(vals) >= 2 and max(vals) - min(vals) <= resolution:
            mid = 0.5 * (max(vals) + min(vals))  # a band one count wide, on these non-negative figures' side of 0
            lo = max(0.0, mid - 0.5 * resolution) if min(vals) >= 0 else mid - 0.5 * resolution
            fig.add_hrect(y0=lo, y1=lo + resolution, row=1, col=i + 1, line_width=0,
                          fillcolor="rgba(120,120,120,0.18)", annotation_text=f"{what}: {resolution:.3g} {u}",
                          annotation_position="top left", annotation_font_size=10)
    fig.update_layout(**{**_LAYOUT, "hovermode": "closest"}, height=300, title="Per cycle")
    return fig


def _num(v: Any) -> float | None:
    return float(v) if isinstance(v, int | float) and math.isfinite(v) else None


def progress_figure(rows: Sequence[dict[str, Any]], sensor: str | None = None) -> go.Figure:
    """Across sessions (one row per run, oldest first): range of motion, peak of the sensor (force,
    torque), tracking RMSE, energy per cycle, against the session's start time; zero-based axes."""
    keys = [("rom_deg", "range of motion [deg]"), ("rmse_deg", "tracking RMSE [deg]"),
            ("energy_per_cycle_j", "energy per cycle [J]")]
    if sensor:
        keys.insert(1, ("peak_force", f"peak {label(sensor)}"))
    fig = make_subplots(rows=2, cols=2, subplot_titles=[k[1] for k in keys], vertical_spacing=0.16)
    x = [r["start"] for r in rows]
    text = [r["label"] for r in rows]
    for i, (k, title) in enumerate(keys):
        fig.add_trace(go.Scatter(x=x, y=[_num(r.get(k)) for r in rows], text=text, mode="lines+markers",
                                 name=title, showlegend=False,
                                 hovertemplate="%{text}<br>%{y:.4g}<extra>" + title + "</extra>"),
                      row=i // 2 + 1, col=i % 2 + 1)
        fig.update_yaxes(title_text=title[title.rindex("[") + 1:-1], rangemode="tozero", row=i // 2 + 1, col=i % 2 + 1)
        fig.update_xaxes(title_text="session start (UTC)", row=i // 2 + 1, col=i % 2 + 1)
    fig.update_layout(**{**_LAYOUT, "hovermode": "closest"}, height=600, title="Progress across sessions")
    return fig
