"""Held-out scoring: effective sample size, BIC, and the significance rule."""

from __future__ import annotations

import numpy as np
import pytest

from rehab_hil.discrepancy.selection import (
    MIN_IMPROVEMENT,
    RESOLUTION_FLOOR,
    bic,
    effective_fraction,
    improvement,
    is_significant,
    resolution_floors,
)


def test_white_residual_counts_every_sample_and_a_smooth_one_few():
    rng = np.random.default_rng(0)
    assert effective_fraction(rng.normal(size=(1, 5000))) > 0.9
    smooth = np.sin(np.linspace(0, 6, 5000))[None, :]
    assert effective_fraction(smooth) < 0.01


def test_bic_prefers_a_smaller_residual_and_penalises_parameters():
    r = np.ones((2, 1000))
    assert bic(0.5 * r, 1, 0.1).bic < bic(r, 0, 0.1).bic
    assert bic(r, 3, 0.1).bic > bic(r, 0, 0.1).bic


def test_significance_needs_both_a_bic_drop_and_a_real_channel_cut():
    r = np.ones((2, 2000))
    base = bic(r, 0, 0.05)
    big = bic(r * np.array([[0.5], [1.0]]), 1, 0.05)
    assert improvement(big, base) == 0.5 and is_significant(big, base)
    tiny = bic(r * (1 - MIN_IMPROVEMENT / 3), 1, 1.0)  # many effective samples: BIC alone would choose it
    base_many = bic(r, 0, 1.0)
    assert tiny.bic < base_many.bic - 10
    assert not is_significant(tiny, base_many)


def test_a_cut_below_the_data_resolution_does_not_count_as_improvement():
    base = bic(np.vstack([np.full(1000, 1e-3), np.ones(1000)]), 0, 0.5)
    cand = bic(np.vstack([np.full(1000, 1e-5), np.ones(1000)]), 1, 0.5)
    assert improvement(cand, base) == 0.0


def test_a_sensor_finer_than_the_spread_floor_resolves_a_smaller_cut():
    t = np.linspace(0.0, 30.0, 30000)
    fine = np.round(30.0 * np.sin(t) / 0.088) * 0.088  # a 4096-count encoder on a 60 deg motion [deg]
    scale = np.array([np.std(fine)])
    floor = resolution_floors(fine[None, :], scale)[0]
    assert floor < RESOLUTION_FLOOR / 2  # one count is ~0.4 % of this spread; its scatter far less
    base = bic(np.full((1, 1000), 0.009), 0, 0.5)
    cand = bic(np.full((1, 1000), 0.0055), 1, 0.5)  # cut 0.0035 of the spread: 0.07 deg
    assert improvement(cand, base) == 0.0  # below the spread floor alone
    assert improvement(cand, base, np.array([floor])) == pytest.approx(1 - 0.0055 / 0.009)
    noisy = 30.0 * np.sin(t) + np.random.default_rng(1).normal(0.0, 2.0, t.size)  # a coarse sensor
    assert resolution_floors(noisy[None, :], np.array([np.std(noisy)]))[0] == RESOLUTION_FLOOR
