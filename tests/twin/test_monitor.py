"""The residual test: quiet on a stationary residual however noisy, fires within a few segments of
a step in it, dates the start where the CUSUM left zero, and watches again after learning the new level."""

from __future__ import annotations

import numpy as np

from rehab_hil.twin.monitor import MonitorSettings, ResidualMonitor

SEG = 0.25


def _run(levels: np.ndarray, noise: float, seed: int = 0, settings: MonitorSettings | None = None):
    mon = ResidualMonitor(["angle_deg"], [0.1], settings or MonitorSettings(learn_s=5.0, settle_s=0.5))
    rng = np.random.default_rng(seed)
    events = []
    for k, level in enumerate(levels):
        rms = abs(level + rng.normal(0.0, noise)) * 0.1  # counts -> degrees
        events += mon.update(k * SEG, (k + 1) * SEG, [rms])
    return mon, events


def test_a_stationary_residual_raises_nothing_over_an_hour_of_segments() -> None:
    mon, events = _run(np.full(14_400, 0.6), noise=0.1)
    assert mon.armed and events == []


def test_a_step_of_two_counts_is_flagged_within_two_segments_and_dated_at_its_start() -> None:
    levels = np.r_[np.full(120, 0.5), np.full(40, 2.5)]  # the change at segment 120 = 30 s
    _, events = _run(levels, noise=0.05)
    assert len(events) == 1
    ev = events[0]
    assert 30.0 <= ev.detected_s <= 30.0 + 2 * SEG
    assert abs(ev.t_s - 30.0) <= SEG
    assert ev.channel == "angle_deg" and 1.5 < ev.size_counts < 2.5


def test_a_rise_smaller_than_the_allowed_excess_is_not_an_event() -> None:
    _, events = _run(np.r_[np.full(120, 0.5), np.full(200, 0.8)], noise=0.05)
    assert events == []


def test_after_an_event_the_new_level_is_learned_and_a_second_change_is_seen() -> None:
    s = MonitorSettings(learn_s=5.0, settle_s=0.5)
    levels = np.r_[np.full(120, 0.5), np.full(120, 2.5), np.full(40, 6.0)]
    mon, events = _run(levels, noise=0.05, settings=s)
    assert [round(e.t_s) for e in events] == [30, 60]
    assert mon.channels[0].first_mu < 0.6  # the session's normal level is the first one learned


def test_nothing_is_judged_while_learning() -> None:
    _, events = _run(np.r_[np.full(10, 0.5), np.full(20, 9.0)], noise=0.0)
    assert events == []  # 7.5 s: the first 5.5 s learn, the rest is learning the high level itself
