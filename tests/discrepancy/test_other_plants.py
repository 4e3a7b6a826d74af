"""The workflow on the TCP finger and the SMA exoskeleton, with the effects that apply to them."""

from __future__ import annotations

import pytest

from rehab_hil.discrepancy.synthetic import hidden_effect_recording
from rehab_hil.discrepancy.workflow import Options, find_missing_effects
from rehab_hil.effects import applicable
from rehab_hil.loading import load_config
from rehab_hil.plants import get_plant

from .conftest import ROOT

# the module fixtures are built once: every test of the module runs on one xdist worker
pytestmark = pytest.mark.xdist_group("test_other_plants")


def _applicable(plant: str) -> set[str]:
    return {e.name for e in applicable(get_plant(plant).ports(load_config(ROOT / "configs" / f"{plant}.toml")))}


def test_thermal_and_finger_effects_apply_to_the_other_plants():
    assert {"nonlinear_convection", "time_delay", "passive_muscle"} <= _applicable("tcp_finger")
    assert {"sma_hysteresis", "contact_spring_damper", "passive_muscle", "time_delay"} <= _applicable("sma_exoskeleton")


@pytest.mark.slow
def test_tcp_finger_hidden_nonlinear_convection_is_found():
    spec, cfg = get_plant("tcp_finger"), load_config(ROOT / "configs" / "tcp_finger.toml")
    true = 2e-5
    rec = hidden_effect_recording(spec, cfg, {"nonlinear_convection": {"coefficient_w_per_k3": true}},
                                  duration_s=20.0, seed=1)
    res = find_missing_effects(cfg, rec, "tcp.csv", options=Options(max_effects=1))
    assert res.named == ["nonlinear_convection"]
    assert res.chosen[0].params["coefficient_w_per_k3"] == pytest.approx(true, rel=0.15)
    before, after = res.metrics("nominal", "holdout"), res.metrics("augmented", "holdout")
    assert after["tcp_temperature_c"]["rmse"] <= 0.5 * before["tcp_temperature_c"]["rmse"]


@pytest.fixture(scope="module")
def sma():
    return get_plant("sma_exoskeleton"), load_config(ROOT / "configs" / "sma_exoskeleton.toml")


@pytest.mark.slow
@pytest.mark.parametrize(("effect", "true", "rel"), [
    ("sma_hysteresis", {"width_c": 8.0}, 0.15),
    ("passive_muscle", {"scale_nm": 0.02, "shape_per_rad": 2.0, "damping_nm_s_per_rad": 0.0}, 0.2),
])
def test_sma_exoskeleton_hidden_effect_is_named_fitted_and_closes_the_gap(sma, effect, true, rel):
    spec, cfg = sma
    rec = hidden_effect_recording(spec, cfg, {effect: true}, duration_s=10.0, seed=3)
    res = find_missing_effects(cfg, rec, "sma.csv", options=Options(max_effects=1))
    assert res.named == [effect]
    for name, value in true.items():
        if value:
            assert res.chosen[0].params[name] == pytest.approx(value, rel=rel), name
    before, after = res.metrics("nominal", "holdout"), res.metrics("augmented", "holdout")
    assert after["theta_mcp_deg"]["rmse"] <= 0.5 * before["theta_mcp_deg"]["rmse"]


@pytest.mark.slow
def test_sma_exoskeleton_clean_data_names_no_effect(sma):
    spec, cfg = sma
    rec = hidden_effect_recording(spec, cfg, {}, duration_s=10.0, seed=4)
    assert find_missing_effects(cfg, rec, "sma.csv", options=Options(max_effects=1)).named == []
