"""The report's figures: the envelope keeps every peak, events sit at their time."""

from __future__ import annotations

import numpy as np

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
    assert {"angle [deg]", "force / sensor", "est. actuator temperature [C]", "duty"} <= rows
