"""The report's figures: the envelope keeps every peak, events sit at their time."""

from __future__ import annotations

import numpy as np
import pytest

from rehab_hil.report import figures
from rehab_hil.report.runs import load_run


def test_envelope_keeps_each_buckets_min_and_max_in_time_order():
    rng = np.random.default_rng(4)
    t = np.arange(600_000) / 1000.0
    y = rng.normal(size=t.size)
    y[123_457] = 50.0  # a single-sample spike
    tt, yy = figures.envelope(t, y, 1500)
    assert tt.size <= 3000 and np.all(np.diff(tt) > 0)
    assert yy.max() == 50.0 and yy.min() == y.min()
    edges = np.linspace(0, t.size, 1501).astype(int)
    for s, e in zip(edges[:-1:97], edges[1::97], strict=True):  # a sample of the buckets
        inside = (tt >= t[s]) & (tt <= t[e - 1])
        assert yy[inside].max() == y[s:e].max() and yy[inside].min() == y[s:e].min()


def test_a_short_record_is_drawn_whole():
    t = np.arange(100.0)
    tt, yy = figures.envelope(t, t**2, 1500)
    assert np.array_equal(tt, t) and np.array_equal(yy, t**2)


def test_session_figure_marks_each_safety_event_at_its_time(tmp_path, make_run):
    run = load_run(make_run(tmp_path, "r", events=[{"t_s": 6.25, "reason": "force_limit", "detail": "9 N"}]))
    fig = figures.session_figure(run)
    assert [s.x0 for s in fig.layout.shapes] == [6.25] * len(fig.layout.shapes) and fig.layout.shapes
    assert "force_limit" in [a.text for a in fig.layout.annotations]
    rows = {a.text for a in fig.layout.annotations}
    assert {"MCP joint angle [deg]", "contact force [N]", "estimated actuator temperature [°C]",
            "applied duty [0-1]"} <= rows  # each row named as a person reads it, with its unit


def _set_cycles(run_dir, key: str, values: list[float]) -> None:
    import json

    path = run_dir / "metadata.json"
    meta = json.loads(path.read_text())
    for c, v in zip(meta["session_cycles"], values, strict=True):
        c[key] = v
    path.write_text(json.dumps(meta))


def test_per_cycle_plots_have_zero_based_axes_whole_cycle_ticks_and_units(tmp_path, make_run):
    run = load_run(make_run(tmp_path, "r", peak_forces=(1.0, 2.0, 3.0)))
    fig = figures.cycle_trend_figure(run)
    titles = [a.text for a in fig.layout.annotations]
    assert titles[:4] == ["range of motion [deg]", "peak contact force [N]", "tracking RMSE [deg]",
                          "electrical energy [J]"]
    for i in range(1, 5):
        x, y = fig.layout[f"xaxis{'' if i == 1 else i}"], fig.layout[f"yaxis{'' if i == 1 else i}"]
        assert y.rangemode == "tozero" and y.title.text  # a unit on every axis
        assert x.dtick == 1 and x.title.text == "cycle"  # no 0.5-cycle ticks


def test_a_change_across_cycles_below_one_encoder_count_is_a_band_not_a_slope(tmp_path, make_run):
    d = make_run(tmp_path, "r")  # 4096 counts/rev: one count is 0.088 deg
    _set_cycles(d, "rom_deg", [30.0, 30.002, 30.004])  # 0.004 deg: noise
    _set_cycles(d, "rmse_deg", [0.5, 0.3, 0.1])  # a real trend
    fig = figures.cycle_trend_figure(load_run(d))
    bands = [s for s in fig.layout.shapes if s.type == "rect"]
    assert len(bands) == 1 and bands[0].xref == "x domain"  # the range of motion's plot only
    assert bands[0].y1 - bands[0].y0 == pytest.approx(360 / 4096) and bands[0].y0 < 30.0 < 30.004 < bands[0].y1
    assert any("one encoder count: 0.0879 deg" in (a.text or "") for a in fig.layout.annotations)


def test_the_stop_rows_carry_no_reference_in_the_session_plot(tmp_path, make_run):
    new = load_run(make_run(tmp_path, "new", events=[{"t_s": 6.5, "reason": "force_limit", "detail": ""}],
                            requested_s=30.0))
    old = load_run(make_run(tmp_path, "old", events=[{"t_s": 6.5, "reason": "force_limit", "detail": ""}]))
    for run in (new, old):  # today's empty cells, and an older run's 0 deg read as none
        after = run.t > 6.5
        assert np.isnan(run.reference[after]).all() and np.isfinite(run.reference[~after]).all()
        ref = figures.session_figure(run).data[0]
        x, y = np.asarray(ref.x, float), np.asarray(ref.y, float)
        assert ref.name == "reference" and x[-1] > 13.0  # drawn to the record's end ...
        assert np.isnan(y[x > 6.51]).all() and np.isfinite(y[x < 6.49]).all()  # ... as a gap after the stop
