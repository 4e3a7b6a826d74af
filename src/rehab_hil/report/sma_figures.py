"""The SMA exoskeleton model against seed 000's figures as an HTML page (the session report's kind):
the 32 V bend (joint angles, wire temperature, contact force and SMA tension over time, the
paper's maximum angles marked) and the PWM staircase of Fig. 10 (MCP angle at equilibrium per
duty). ``python -m rehab_hil.analysis.sma_experiments --html FILE`` writes it."""

from __future__ import annotations

from typing import Any

import numpy as np
import plotly.graph_objects as go
from plotly.subplots import make_subplots

from rehab_hil.report.figures import SESSION_BUCKETS, envelope
from rehab_hil.report.page import Page, table

__all__ = ["sma_figures_page"]


def _line(t: np.ndarray, y: Any, **kw: Any) -> go.Scatter:
    tt, yy = envelope(t, np.asarray(y, float), SESSION_BUCKETS)
    return go.Scatter(x=tt.astype(np.float32), y=yy.astype(np.float32), mode="lines", **kw)


def sma_figures_page(bend: Any, sweep: dict[float, float], figures: dict[str, Any], paper: dict[str, Any]) -> Page:
    """``bend``: the pwm-step SimulationResult; ``sweep``: duty -> MCP deg; ``figures``: ``report()``."""
    page = Page("rehab-hil: SMA exoskeleton model against seed 000")
    t = np.asarray(bend.t, float)
    fig = make_subplots(rows=3, cols=1, shared_xaxes=True, vertical_spacing=0.06,
                        subplot_titles=["joint angles [deg]", "SMA wire temperature [C]", "force [N]"])
    for j, dash in (("mcp", "solid"), ("pip", "dash"), ("dip", "dot")):
        fig.add_trace(_line(t, bend[f"theta_{j}_deg"], name=f"theta_{j}_deg (model)", line={"dash": dash}), row=1,
                      col=1)
        fig.add_hline(y=paper[f"max_{j}_deg"], line={"dash": dash, "color": "#999", "width": 1}, row=1, col=1,
                      annotation_text=f"paper max {j.upper()} {paper[f'max_{j}_deg']} deg")
    fig.add_trace(_line(t, bend["sma_temperature_c"], name="sma_temperature_c", line={"color": "#d62728"}), row=2,
                  col=1)
    for name in ("contact_force_n", "sma_tension_n"):
        fig.add_trace(_line(t, bend[name], name=name), row=3, col=1)
    fig.update_xaxes(title_text="time [s] (32 V, duty 1 for 5 s, then cooling)", row=3, col=1)
    fig.update_layout(template="plotly_white", height=800, title="The 32 V bend (Fig. 7-9)",
                      margin={"l": 60, "r": 20, "t": 70, "b": 40}, legend={"orientation": "h", "y": -0.08})
    page.figure(fig)
    duties = sorted(sweep)
    sw = go.Figure(go.Scatter(x=duties, y=[sweep[d] for d in duties], mode="lines+markers", name="model"))
    sw.update_layout(template="plotly_white", height=380, title="PWM staircase (Fig. 10): MCP angle at equilibrium",
                     xaxis_title="duty", yaxis_title="theta_mcp_deg", margin={"l": 60, "r": 20, "t": 70, "b": 40})
    page.figure(sw)
    bend_fig = figures.get("bending") or {}
    page.heading("Figures against the paper")
    rows = [[k, v, paper.get(k)] for k, v in bend_fig.items() if isinstance(v, int | float)]
    page.raw(table(["bend metric", "model", "paper"], rows))
    return page
