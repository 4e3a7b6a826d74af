"""SPARC and the log dimensionless jerk, pinned to the reference implementation's published example
values (Balasubramanian's ``scripts/smoothness.py`` in github siva82kb/SPARC, its docstring examples:
a Gaussian speed profile exp(-5 t^2), t in [-1, 1) at 100 Hz, gives SPARC -1.41403 and log dimensionless
jerk -5.81636, with the defaults padlevel 4, fc 10 Hz, amplitude threshold 0.05)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from rehab_hil.smoothness import log_dimensionless_jerk, sparc


def _gaussian():
    t = np.arange(-1, 1, 0.01)
    return np.exp(-5 * t**2)


def test_sparc_equals_the_reference_implementations_published_example():
    assert f"{sparc(_gaussian(), 100.0):.5f}" == "-1.41403"


def test_log_dimensionless_jerk_equals_the_reference_implementations_published_example():
    assert f"{log_dimensionless_jerk(_gaussian(), 100.0):.5f}" == "-5.81636"


def test_a_movement_made_of_two_submovements_is_less_smooth_on_both_measures():
    t = np.arange(-1, 1, 0.01)
    two = np.exp(-20 * (t + 0.35) ** 2) + np.exp(-20 * (t - 0.35) ** 2)
    assert sparc(two, 100.0) < sparc(_gaussian(), 100.0) - 0.2
    assert log_dimensionless_jerk(two, 100.0) < log_dimensionless_jerk(_gaussian(), 100.0) - 0.5


@pytest.mark.parametrize("speed", [np.zeros(50), np.array([1.0])])
def test_no_motion_has_no_smoothness(speed):
    assert math.isnan(sparc(speed, 100.0))
    assert math.isnan(log_dimensionless_jerk(speed, 100.0))


def test_a_speed_whose_square_underflows_is_no_motion_not_an_error():
    # a finger at rest reads speeds like 1e-200 rad/s: the measures run in the loop and must not raise
    speed = np.full(400, 1e-200)
    assert math.isnan(log_dimensionless_jerk(speed, 100.0))
    assert math.isfinite(sparc(speed, 100.0))
