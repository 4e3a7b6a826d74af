"""Seed 000 experiments on the plant: the regression finds the pad's k and c in a simulated bend,
and the PWM sweep rises monotonically with duty."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from rehab_hil.analysis import sma_experiments as ex
from rehab_hil.loading import load_config

CFG_PATH = Path(__file__).resolve().parents[2] / "configs" / "sma_exoskeleton.toml"


@pytest.fixture(scope="module")
def run():
    cfg = load_config(CFG_PATH)
    system = ex.compile_plant(cfg)
    return cfg, system, ex.bending(cfg, system)[0]


@pytest.mark.slow
def test_signed_regression_recovers_the_pads_k_and_c_from_the_simulated_bend(run):
    cfg, _, res = run
    fit = ex.regression_on_run(res, signed=True)
    k_true = cfg.contact.stiffness_n_per_m / 1e3  # N/mm
    c_true = cfg.contact.damping_n_s_per_m / 1e3  # N/(mm/s)
    assert fit.k_n_per_mm == pytest.approx(k_true, rel=0.05)  # 3 % force noise
    assert fit.c_n_s_per_mm == pytest.approx(c_true, rel=0.1)


@pytest.mark.slow
def test_regressing_on_magnitudes_as_eq18_does_not_find_the_positive_damping(run):
    _, _, res = run
    fit = ex.regression_on_run(res, signed=False)
    assert fit.c_n_s_per_mm < 0.5 * run[0].contact.damping_n_s_per_m / 1e3


@pytest.mark.slow
def test_steady_mcp_angle_does_not_fall_as_the_duty_rises(run):
    cfg, system, _ = run
    sweep = ex.pwm_sweep(cfg, system)
    angles = np.array([sweep[d] for d in sorted(sweep)])
    assert np.all(np.diff(angles) >= -1e-6)
    assert angles[0] > 0.0
