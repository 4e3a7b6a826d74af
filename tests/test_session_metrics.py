"""Per-cycle session figures: computed from a record whose answers are known by construction."""

from __future__ import annotations

import math

import numpy as np
import pytest

from rehab_hil.controllers import Reference
from rehab_hil.session_metrics import SessionMeter, cycle_metrics, session_summary

REF = Reference("session", 0.0, 40.0, move_s=2.0, hold_open_s=3.0, hold_closed_s=3.0)  # 10 s cycles


def record(lag_s: float, cycles: int = 3, dt: float = 0.001):
    """The reference, and an angle that follows it ``lag_s`` late; 10 W while opening or open."""
    t = np.arange(0.0, REF.first_open_s + cycles * REF.period_s, dt)
    r = REF.values(t)
    y = REF.values(t - lag_s)
    power = np.where(r > 0.0, 10.0, 0.0)
    return t, r, y, power


def test_a_perfect_follower_scores_zero_error_full_range_and_the_move_time():
    t, r, y, p = record(0.0)
    cyc = cycle_metrics(t - REF.first_open_s, r, y, p, None, REF.period_s, REF.move_s, 0.0, 40.0)
    assert len(cyc) == 3 and all(c.rmse_deg == 0.0 for c in cyc)
    c = cyc[1]
    assert c.rom_deg == pytest.approx(40.0)
    # within 5 % of the span (2 deg) of open: the raised cosine 20 (1 - cos(pi t / move)) reaches 38 deg
    # where cos(pi t / move) = -0.9
    assert c.time_to_open_s == pytest.approx(REF.move_s * (1 - math.acos(0.9) / math.pi), abs=0.01)
    assert c.energy_j == pytest.approx(10.0 * (2 * REF.move_s + REF.hold_open_s), rel=0.01)
    assert math.isnan(c.peak_temperature_c)


def test_a_lagging_follower_shows_its_lag_in_the_times_and_errors():
    t, r, y, p = record(0.5)
    lag = session_summary(cycle_metrics(t - REF.first_open_s, r, y, p, 40.0 + 0 * t, REF.period_s, REF.move_s,
                                        0.0, 40.0))
    t0, r0, y0, p0 = record(0.0)
    ok = session_summary(cycle_metrics(t0 - REF.first_open_s, r0, y0, p0, None, REF.period_s, REF.move_s, 0.0, 40.0))
    assert lag["time_to_open_s"] == pytest.approx(ok["time_to_open_s"] + 0.5, abs=0.01)
    assert lag["time_to_closed_s"] == pytest.approx(ok["time_to_closed_s"] + 0.5, abs=0.01)
    assert lag["rmse_deg"] > 5.0 and lag["peak_temperature_c"] == 40.0


def test_a_cut_short_last_cycle_is_left_out():
    t, r, y, p = record(0.0)
    keep = t < REF.first_open_s + 2.5 * REF.period_s
    cyc = cycle_metrics(t[keep] - REF.first_open_s, r[keep], y[keep], p[keep], None, REF.period_s, REF.move_s,
                        0.0, 40.0)
    assert len(cyc) == 2


def test_the_live_meter_reports_each_cycle_once_it_ends_with_the_offline_figures():
    t, r, y, p = record(0.3)
    meter = SessionMeter(len(t), REF.period_s, REF.move_s, REF.first_open_s, 0.0, 40.0, lambda e, v: e)
    live = []
    for k in range(len(t)):
        meter.add(t[k], r[k], y[k], p[k], 0.0, math.nan)
        c = meter.poll()
        if c is not None:
            live.append((t[k], c))
    offline = cycle_metrics(t - REF.first_open_s, r, y, p, None, REF.period_s, REF.move_s, 0.0, 40.0)
    assert [c.index for _, c in live] == [0, 1] and len(offline) == 3  # the third ends with the record
    for (t_end, c), o in zip(live, offline, strict=False):
        assert t_end == pytest.approx(REF.first_open_s + (c.index + 1) * REF.period_s, abs=0.002)
        assert c.rmse_deg == pytest.approx(o.rmse_deg, rel=1e-3) and c.energy_j == pytest.approx(o.energy_j, rel=1e-3)


def test_a_cycle_at_rest_gets_its_figures_and_no_measure_raises():
    # the TCP finger's capable patient left the joint still to 1e-200 rad/s: LDLJ once divided by zero in the loop
    meter = SessionMeter(3000, 2.0, 0.5, 0.0, 0.0, 10.0, lambda e, v: np.zeros_like(e))
    for k in range(2100):
        meter.add(k * 0.001, 0.0, 0.0, 0.0, 1e-200, 20.0)
    cycle = meter.poll()
    assert cycle is not None and cycle.as_dict()["success_open"] == 0.0


def test_a_rig_that_pulls_one_way_counts_its_success_in_the_move_it_drives() -> None:
    """A follower that bends to the open target but never comes back below 10 deg (a flexed finger an
    SMA wire, which only flexes, cannot return): half its moves succeed, all of those the rig drives."""
    t, r, y, p = record(0.0)
    y = np.maximum(y, 10.0)
    both = SessionMeter(len(t), REF.period_s, REF.move_s, REF.first_open_s, 0.0, 40.0, lambda e, v: e)
    one_way = SessionMeter(len(t), REF.period_s, REF.move_s, REF.first_open_s, 0.0, 40.0, lambda e, v: e,
                           assisted=("open",))
    for meter in (both, one_way):
        for k in range(len(t)):
            meter.add(t[k], r[k], y[k], p[k], 0.0, math.nan)
            meter.poll()
    assert [c.measures["success"] for c in one_way.cycles] == [0.5, 0.5]
    assert [c.measures["success_assisted"] for c in one_way.cycles] == [1.0, 1.0]
    assert [c.measures["success_assisted"] for c in both.cycles] == [0.5, 0.5]
    assert one_way.summary()["success_assisted"] == 1.0
