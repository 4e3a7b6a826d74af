"""Joint identification (discrepancy/identify.py): what a record cannot separate is said so, and a
physically coupled group (a weaker magnet: k_t and k_v together) is found as the group, on the
independent Finger Extensor simulator (bench/discrepancy.py)."""

from __future__ import annotations

import numpy as np
import pytest

from rehab_hil.discrepancy.identify import _weak_direction
from rehab_hil.discrepancy.report import augmented_toml
from rehab_hil.discrepancy.workflow import Options, find_missing_effects
from rehab_hil.loading import load_config

from .conftest import FE_CONFIG

FLUX = "motor.flux (kt_nm_per_a and kv_v_s_per_rad)"


def test_two_sensitivities_in_proportion_are_one_unseen_direction_with_both_members() -> None:
    rng = np.random.default_rng(0)
    a, b = rng.normal(size=200), rng.normal(size=200)
    weak = _weak_direction(np.column_stack([a, -2.0 * a + 1e-4 * rng.normal(size=200), b]))
    assert weak is not None
    assert np.abs(weak[:2]).min() > 0.5 and abs(weak[2]) < 0.05
    assert _weak_direction(np.column_stack([a, b])) is None  # independent columns: nothing unseen


@pytest.mark.slow
def test_a_weaker_magnet_is_reported_as_the_motor_flux_group_and_both_keys_corrected(fe, independent, tmp_path):
    _spec, cfg = fe
    rec = independent.fe_record({}, {"kt": -0.15, "kv": -0.15}, 4, duration_s=12.0, rate_hz=500.0)
    res = find_missing_effects(cfg, rec, "magnet.csv", options=Options(max_effects=1))
    assert res.named == [] and [f.effect for f in res.parameters] == [FLUX], res.conclusion
    assert res.parameters[0].params["error_fraction"] == pytest.approx(-0.15, abs=0.02)
    (tmp_path / "aug.toml").write_text(augmented_toml(res, FE_CONFIG))
    fixed = load_config(tmp_path / "aug.toml")
    f = 1 + res.parameters[0].params["error_fraction"]
    assert fixed.motor.kt_nm_per_a == pytest.approx(0.791 * f)
    assert fixed.motor.kv_v_s_per_rad == pytest.approx(0.886 * f)
