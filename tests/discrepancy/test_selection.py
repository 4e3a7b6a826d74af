"""Held-out scoring: effective sample size, BIC, and the significance rule."""

from __future__ import annotations

import numpy as np

from rehab_hil.discrepancy.selection import MIN_IMPROVEMENT, bic, effective_fraction, improvement, is_significant


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


def test_channel_weights_change_the_bic_but_not_the_channel_errors():
    """A noisy channel weighed down (``Replay.fit_weight``) counts less in the BIC; its RMS error, which
    the improvement rule reads, stays in the scaled unit."""
    r = np.vstack([np.full(1000, 0.01), np.full(1000, 0.3)])
    plain, weighted = bic(r, 0, 0.5), bic(r, 0, 0.5, weight=np.array([1.0, 0.1]))
    assert weighted.channel_rms == plain.channel_rms
    assert weighted.bic < plain.bic
    better_noisy = bic(r * np.array([[1.0], [0.5]]), 1, 0.5, weight=np.array([1.0, 0.1]))
    better_sharp = bic(r * np.array([[0.5], [1.0]]), 1, 0.5, weight=np.array([1.0, 0.1]))
    assert better_noisy.bic < weighted.bic and better_sharp.bic < weighted.bic
