"""Tendon torque split (seed 001 eq 6): tau_k = fraction_k x F x e."""

from __future__ import annotations

import numpy as np
import pytest

from rehab_hil.models.tcp_tendon import TendonTorqueSplit


def test_each_joint_gets_its_fraction_of_force_times_offset():
    y = np.zeros(3)
    p = np.array([0.0045, 0.25, 0.22, 0.20])
    TendonTorqueSplit.output(0.0, np.zeros(0), np.zeros(0), np.array([3.0]), p, y)
    np.testing.assert_allclose(y, [0.25 * 3.0 * 0.0045, 0.22 * 3.0 * 0.0045, 0.20 * 3.0 * 0.0045])


def test_no_force_no_torque_and_the_sign_follows_the_force():
    y = np.zeros(3)
    p = np.array([0.0045, 0.25, 0.22, 0.20])
    TendonTorqueSplit.output(0.0, np.zeros(0), np.zeros(0), np.array([0.0]), p, y)
    assert np.all(y == 0.0)
    TendonTorqueSplit.output(0.0, np.zeros(0), np.zeros(0), np.array([-1.0]), p, y)
    assert y[0] == pytest.approx(-0.25 * 0.0045)
