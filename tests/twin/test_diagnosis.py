"""The twin's quick diagnosis names the likeliest cause of a mid-session change (issue 23, item 4).

Windows come from the plant models: ``hidden_effect_recording`` (an effect hidden in the whole
record, cut mid-way, no state given: the workflow's start estimate) and ``changed_window`` (the
plant changes at the window's start, the twin's state there given)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from rehab_hil.discrepancy.synthetic import hidden_effect_recording
from rehab_hil.interchange import Recording
from rehab_hil.loading import load_config
from rehab_hil.plants import get_plant
from rehab_hil.plants.sections import EffectSpec
from rehab_hil.twin.diagnosis import changed_window, diagnose, rig_channels

# the module fixtures are built once: every test of the module runs on one xdist worker
pytestmark = pytest.mark.xdist_group("test_diagnosis")

CONFIGS = Path(__file__).resolve().parents[2] / "configs"


def _plant(name: str):
    return get_plant(name), load_config(CONFIGS / f"{name}.toml")


@pytest.fixture(scope="module")
def fe():
    return _plant("finger_extensor")


@pytest.fixture(scope="module")
def sma():
    return _plant("sma_exoskeleton")


def _cut(spec, cfg, rec: Recording, start_s: float, end_s: float) -> Recording:
    """The rig's columns of ``rec`` between two instants."""
    keep = rig_channels(spec, cfg)
    m = (rec.t >= start_s) & (rec.t < end_s)
    return Recording(rec.t[m], {k: v[m] for k, v in rec.signals.items() if k in keep})


def test_coulomb_friction_hidden_mid_record_is_named_first_without_a_start_state(fe):
    spec, cfg = fe
    rec = hidden_effect_recording(spec, cfg, {"coulomb_friction": {"level_nm": 0.03}}, duration_s=8.0, seed=2)
    d = diagnose(spec, cfg, _cut(spec, cfg, rec, 4.0, 8.0))  # the finger moves at 4 s: its state is estimated
    assert d.likeliest is not None and d.likeliest.name == "coulomb_friction", d.text
    # named, its size only roughly: from an estimated start in shooting mode the short fit reaches
    # 0.013 N m of the true 0.03 (with the twin's state, the next test, within 20 %)
    assert 0.01 < d.likeliest.params["level_nm"] < 0.045
    assert d.text.startswith("friction appearing: coulomb_friction")
    assert d.likeliest.reduction > 0.5
    assert d.causes[0] is d.likeliest and all(c.reduction <= 1.0 for c in d.causes)


def test_coulomb_friction_appearing_at_the_window_start_with_the_twin_state(fe):
    spec, cfg = fe
    w = changed_window(spec, cfg, effects={"coulomb_friction": {"level_nm": 0.03}}, seed=1)
    d = diagnose(spec, cfg, w.recording, w.x0, w.xd0)
    assert d.likeliest is not None and d.likeliest.name == "coulomb_friction", d.text
    assert d.likeliest.params["level_nm"] == pytest.approx(0.03, rel=0.2)
    assert d.likeliest.relative_change is None  # an effect from nothing has no relative change


def test_patient_contact_stiffness_doubling_is_named_as_the_configured_effect_plus_100_percent(fe):
    spec, cfg = fe
    contact = {"stiffness_nm_per_rad": 0.3, "damping_nm_s_per_rad": 0.0, "contact_angle_rad": 0.4}
    patient = cfg.model_copy(update={"effects": [EffectSpec(name="contact_spring_damper", params=contact)]})
    w = changed_window(spec, patient, effects={"contact_spring_damper": contact}, seed=1)  # the same again: k x 2
    d = diagnose(spec, patient, w.recording, w.x0, w.xd0)
    assert d.likeliest is not None and d.likeliest.family == "passive stiffness", d.text
    assert d.likeliest.name == "effects.0.params.stiffness_nm_per_rad"
    assert d.likeliest.relative_change == pytest.approx(1.0, abs=0.15)
    assert d.text.startswith("passive stiffness rising: contact_spring_damper.stiffness_nm_per_rad")
    assert "+9" in d.text or "+10" in d.text


def test_a_patient_contact_stiffening_as_a_whole_is_named_as_the_whole_effect_and_a_stiffer_spring_alone_is_not(fe):
    spec, cfg = fe
    contact = {"stiffness_nm_per_rad": 1.0, "damping_nm_s_per_rad": 0.025, "contact_angle_rad": 0.4}
    patient = cfg.model_copy(update={"effects": [EffectSpec(name="contact_spring_damper", params=contact)]})
    w = changed_window(spec, patient, effects={"contact_spring_damper": contact}, seed=1)  # k and c x 2
    d = diagnose(spec, patient, w.recording, w.x0, w.xd0)
    assert d.likeliest is not None and d.likeliest.name == "effects.0.params", d.text
    assert d.likeliest.relative_change == pytest.approx(1.0, abs=0.1)
    assert d.text.startswith("passive stiffness rising: contact_spring_damper as a whole (effects.0.params), +")

    spring = {**contact, "damping_nm_s_per_rad": 0.0}
    w = changed_window(spec, patient, effects={"contact_spring_damper": spring}, seed=1)  # k x 2 only
    d = diagnose(spec, patient, w.recording, w.x0, w.xd0)
    assert d.likeliest is not None and d.likeliest.name == "effects.0.params.stiffness_nm_per_rad", d.text


def test_passive_muscle_appearing_on_the_sma_finger_is_a_passive_stiffness(sma):
    spec, cfg = sma
    w = changed_window(spec, cfg, effects={"passive_muscle": {"scale_nm": 0.02, "shape_per_rad": 2.0,
                                                              "damping_nm_s_per_rad": 0.0}}, seed=2)
    d = diagnose(spec, cfg, w.recording, w.x0, w.xd0)
    assert d.likeliest is not None and d.likeliest.family == "passive stiffness", d.text
    assert d.text.startswith("passive stiffness rising:")


def test_supply_sagging_8_percent_is_named_as_the_supply_parameter(sma):
    spec, cfg = sma
    # the wire sees 92 % of the supply; the rig logs the config's constant, as rig_recording fills it
    w = changed_window(spec, cfg, input_scale={"supply_voltage_v": 0.92}, seed=2)
    assert np.all(w.recording["supply_voltage_v"] == cfg.drive.supply_voltage_v)
    d = diagnose(spec, cfg, w.recording, w.x0, w.xd0)
    assert d.likeliest is not None and d.likeliest.name == "drive.supply_voltage_v", d.text
    assert d.likeliest.relative_change == pytest.approx(-0.08, abs=0.015)
    assert d.text == "supply sagging: drive.supply_voltage_v, -8 %"


def test_supply_sag_beats_the_driver_dead_zone_it_ties_with_at_one_duty_level(sma):
    spec, cfg = sma
    w = changed_window(spec, cfg, input_scale={"supply_voltage_v": 0.92}, seed=1)  # one duty level in the window
    d = diagnose(spec, cfg, w.recording, w.x0, w.xd0)
    names = [c.name for c in d.causes]
    assert names[0] == "drive.supply_voltage_v", d.text
    assert "actuator_dead_zone" in names[1:3]  # explains it as well, named after the parameter


def test_sma_wire_losing_15_percent_of_its_prestrain_is_named(sma):
    spec, cfg = sma
    worn = cfg.model_copy(update={"sma": cfg.sma.model_copy(update={"prestrain": 0.85 * cfg.sma.prestrain})})
    w = changed_window(spec, cfg, config=worn, seed=2)
    d = diagnose(spec, cfg, w.recording, w.x0, w.xd0)
    assert d.likeliest is not None and d.likeliest.name == "sma.prestrain", d.text
    assert d.likeliest.relative_change == pytest.approx(-0.15, abs=0.03)
    assert d.text.startswith("SMA wire losing prestrain: sma.prestrain, -1")


@pytest.mark.parametrize("plant", ["finger_extensor", "sma_exoskeleton", "tcp_finger"])
def test_a_clean_window_names_no_cause(plant):
    spec, cfg = _plant(plant)
    w = changed_window(spec, cfg, seed=2)
    d = diagnose(spec, cfg, w.recording, w.x0, w.xd0)
    assert d.likeliest is None, d.text
    assert d.text.startswith("no ")
    rec = hidden_effect_recording(spec, cfg, {}, duration_s=8.0, seed=2)
    assert diagnose(spec, cfg, _cut(spec, cfg, rec, 4.0, 8.0)).likeliest is None


def test_a_held_duty_is_diagnosed_from_the_twin_state_and_refused_without_it(sma):
    spec, cfg = sma
    w = changed_window(spec, cfg, input_scale={"supply_voltage_v": 0.92}, seed=3)  # duty 0.4 all window
    assert np.ptp(w.recording["pwm_duty"]) == 0.0
    d = diagnose(spec, cfg, w.recording, w.x0, w.xd0)  # the wire heats from the twin's state: a step response
    assert d.likeliest is not None and d.likeliest.name == "drive.supply_voltage_v", d.text
    d = diagnose(spec, cfg, w.recording)  # no state: the workflow's check refuses it, said in the event
    assert d.likeliest is None and d.causes == []
    assert "constant" in d.text


def test_a_state_of_another_layout_is_refused(fe):
    spec, cfg = fe
    w = changed_window(spec, cfg, seed=1)
    with pytest.raises(ValueError, match="x0 has 2 states"):
        diagnose(spec, cfg, w.recording, np.zeros(2))


def test_the_budget_stops_the_screen(sma):
    spec, cfg = sma
    w = changed_window(spec, cfg, input_scale={"supply_voltage_v": 0.92}, seed=2)
    d = diagnose(spec, cfg, w.recording, w.x0, w.xd0, budget_s=0.0)
    assert d.skipped and not any(c.refined for c in d.causes)
    assert d.likeliest is None
