"""What a therapist reads of one cycle, on synthetic cycles whose answers are known."""

from __future__ import annotations

import math

import numpy as np
import pytest

from rehab_hil.therapy_measures import SUCCESS_WINDOW_S, cycle_measures

PERIOD, MOVE, CLOSED, OPEN = 12.0, 3.0, 10.0, 110.0
T = np.arange(0.0, PERIOD, 0.001)


def _tracking(lag_s: float = 0.0, reach: float = 1.0) -> np.ndarray:
    """The cycle's reference, ``lag_s`` late, opening only to ``reach`` of the span [deg]."""
    hold = 0.5 * (PERIOD - 2 * MOVE)
    tc = T - lag_s
    up = CLOSED + reach * (OPEN - CLOSED) * 0.5 * (1 - np.cos(np.pi * np.clip(tc, 0, MOVE) / MOVE))
    down_t = np.clip(tc - MOVE - hold, 0, MOVE)
    return np.where(tc < MOVE + hold, up, up - reach * (OPEN - CLOSED) * 0.5 * (1 - np.cos(np.pi * down_t / MOVE)))


def _measures(angle, torque=None, energy=1.0, baseline=2.0):
    vel = np.radians(np.gradient(angle, T))
    return cycle_measures(T, angle, vel, np.full_like(T, np.nan) if torque is None else torque, PERIOD, MOVE,
                          CLOSED, OPEN, energy, baseline)


def test_a_cycle_that_reaches_both_targets_in_time_succeeds():
    m = _measures(_tracking(lag_s=0.5))
    assert m["success_open"] == m["success_close"] == m["success"] == 1.0
    assert m["active_rom_deg"] == pytest.approx(OPEN - CLOSED, abs=0.01)
    assert m["peak_velocity_deg_s"] == pytest.approx(np.pi / 2 * (OPEN - CLOSED) / MOVE, rel=0.01)
    assert m["assistance_ratio"] == 0.5  # 1 J against the 2 J with a passive finger
    assert -3.0 < m["sparc"] < -1.0 and math.isfinite(m["ldlj"])


def test_a_move_late_by_more_than_the_window_or_short_of_its_target_fails():
    late = _measures(_tracking(lag_s=SUCCESS_WINDOW_S + 1.0))
    assert late["success_open"] == 0.0
    short = _measures(_tracking(reach=0.9))  # 10 % of the span short: outside the 5 % tolerance
    assert short["success_open"] == 0.0 and short["success_close"] == 1.0 and short["success"] == 0.5


def test_torque_measures_need_a_torque_sensor_and_read_its_slopes():
    angle = _tracking()
    m = _measures(angle)
    assert math.isnan(m["patient_torque_open_nm"]) and math.isnan(m["interaction_stiffness_nm_per_rad"])
    torque = 0.3 - 0.2 * np.radians(angle)  # a spring of 0.2 N m/rad and a constant push toward opening
    m = _measures(angle, torque)
    assert m["interaction_stiffness_nm_per_rad"] == pytest.approx(0.2, rel=1e-6)
    assert m["patient_torque_open_ci_nm"] > 0 and m["patient_torque_close_ci_nm"] > 0
    # pushing toward opening the whole cycle: toward the opening target, against the closing one
    assert m["patient_torque_open_nm"] > 0 > m["patient_torque_close_nm"]
    assert math.isnan(_measures(angle, baseline=math.nan)["assistance_ratio"])


def test_a_move_read_one_encoder_count_short_of_the_tolerance_succeeds_and_two_counts_fail():
    """The TCP finger's 2 deg task has a 0.1 deg tolerance under its 0.18 deg count: a finger 0.07 deg
    short read a whole count short and failed. A count is part of the tolerance."""
    count = 0.18
    tol = 0.05 * (OPEN - CLOSED)
    short = np.where(T < 2 * MOVE, np.minimum(_tracking(), OPEN - tol - count + 0.01), _tracking())
    vel = np.radians(np.gradient(short, T))
    none = np.full_like(T, np.nan)
    assert cycle_measures(T, short, vel, none, PERIOD, MOVE, CLOSED, OPEN, 1.0, 2.0)["success_open"] == 0.0
    assert cycle_measures(T, short, vel, none, PERIOD, MOVE, CLOSED, OPEN, 1.0, 2.0, count)["success_open"] == 1.0
    shorter = np.minimum(short, OPEN - tol - 2 * count)
    assert cycle_measures(T, shorter, vel, none, PERIOD, MOVE, CLOSED, OPEN, 1.0, 2.0, count)["success_open"] == 0.0
