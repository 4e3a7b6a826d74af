"""The effect library: bounds, option parsing, attachment, and the new parts' kernels."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from rehab_hil.effects import EFFECTS, applicable, attach, check_spec, parse_effect_option
from rehab_hil.loading import load_config
from rehab_hil.models.effect_parts import DELAY_SLOTS, Backlash, ContactSpringDamper, TransportDelay
from rehab_hil.models.system import Diagram, DiagramError
from rehab_hil.plants import get_plant
from rehab_hil.plants.sections import EffectSpec

CONFIGS = Path(__file__).resolve().parents[1] / "configs"

REQUIRED = {"coulomb_friction", "viscous_friction", "backlash", "time_delay", "contact_spring_damper",
            "passive_muscle", "sma_hysteresis", "nonlinear_convection"}


@pytest.fixture(scope="module")
def fe():
    return get_plant("finger_extensor"), load_config(CONFIGS / "finger_extensor.toml")


def _applicable(plant: str) -> list:
    return applicable(get_plant(plant).ports(load_config(CONFIGS / f"{plant}.toml")))


def test_library_has_every_required_effect_with_bounded_unit_named_params():
    assert REQUIRED <= set(EFFECTS)
    for eff in EFFECTS.values():
        assert eff.seed and eff.description
        for p in eff.params:
            assert "_" in p.name, p.name  # unit in the name
            assert p.lower <= p.typical <= p.upper
            if p.off is not None:
                assert p.lower <= p.off <= p.upper


def test_finger_extensor_gets_the_mechanical_effects():
    names = {e.name for e in _applicable("finger_extensor")}
    assert {"coulomb_friction", "viscous_friction", "backlash", "time_delay", "contact_spring_damper"} <= names
    assert "sma_hysteresis" not in names


def test_check_spec_rejects_unknown_effect_unknown_param_and_out_of_bounds():
    with pytest.raises(ValueError, match="unknown effect 'friction'"):
        check_spec("friction", {})
    with pytest.raises(ValueError, match="no parameters \\['torque_nm'\\]"):
        check_spec("coulomb_friction", {"torque_nm": 0.1})
    with pytest.raises(ValueError, match="outside"):
        check_spec("coulomb_friction", {"level_nm": -0.1})
    assert check_spec("coulomb_friction", {"level_nm": 0.1}) == {"level_nm": 0.1}


def test_parse_effect_option_reads_name_and_params():
    assert parse_effect_option("time_delay:delay_s=0.01") == ("time_delay", {"delay_s": 0.01})
    name, params = parse_effect_option("contact_spring_damper:stiffness_nm_per_rad=1,contact_angle_rad=0.4")
    assert name == "contact_spring_damper" and params == {"stiffness_nm_per_rad": 1.0, "contact_angle_rad": 0.4}
    with pytest.raises(ValueError, match="expected key=value"):
        parse_effect_option("time_delay:delay_s")
    with pytest.raises(ValueError, match="not a number"):
        parse_effect_option("time_delay:delay_s=soon")


def test_attach_inserts_a_delay_on_the_motor_input_and_sums_friction_into_the_iris(fe):
    spec, cfg = fe
    parts = attach(spec.name, spec.ports(cfg), cfg.simulation.step_s, spec.build(cfg),
                   [("time_delay", {"delay_s": 0.01}), ("coulomb_friction", {"level_nm": 0.02})])
    by = {p.name: p for p in parts}
    assert by["motor"].connections["voltage_v"] == [("effect_time_delay_y", 1.0)]
    assert by["effect_time_delay"].connections["u"] == [("motor_voltage_v", 1.0)]
    assert ("effect_coulomb_friction_torque_nm", 1.0) in by["iris"].connections["torque_nm"]


def _wiring(parts) -> list:
    """Each part's name, published signals and input wiring, as plain values (a snapshot)."""
    return [(p.name, tuple(p.signal_names), {port: list(terms) for port, terms in p.connections.items()},
             p.param_values.copy().tolist()) for p in parts]


REWIRING = {  # effects that insert on a wire, sum into a port, take a name over or add onto an axis
    "finger_extensor": [("time_delay", {"delay_s": 0.01}), ("backlash", {"width_rad": 0.02}),
                        ("coulomb_friction", {"level_nm": 0.02}), ("viscous_friction", {}),
                        ("sensor_gain_offset", {"gain_error_fraction": 0.1})],
    "sma_exoskeleton": [("sensor_gain_offset", {"gain_error_fraction": -0.1}), ("sma_hysteresis", {"width_c": 5.0}),
                        ("backlash", {"width_rad": 0.02}), ("coulomb_friction", {"level_nm": 0.005})],
    "tcp_finger": [("time_delay", {"delay_s": 0.01}), ("nonlinear_convection", {}),
                   ("sensor_gain_offset", {"offset_counts": 5.0}), ("passive_muscle", {})],
}


@pytest.mark.parametrize("plant", sorted(REWIRING))
def test_attach_leaves_the_callers_parts_and_their_connections_unchanged(plant):
    spec, cfg = get_plant(plant), load_config(CONFIGS / f"{plant}.toml")
    nominal = spec.build(cfg)
    before = _wiring(nominal)
    parts = attach(spec.name, spec.ports(cfg), cfg.simulation.step_s, nominal, REWIRING[plant])
    assert _wiring(nominal) == before
    assert len(parts) == len(nominal) + len(REWIRING[plant])
    assert _wiring(parts[: len(nominal)]) != before  # the copies were rewired
    assert not {id(p) for p in parts} & {id(p) for p in nominal}


@pytest.mark.parametrize("plant", sorted(REWIRING))
def test_attaching_twice_to_one_nominal_list_gives_identical_diagrams(plant):
    spec, cfg = get_plant(plant), load_config(CONFIGS / f"{plant}.toml")
    nominal = spec.build(cfg)
    ports = spec.ports(cfg)
    first, second = (Diagram(attach(spec.name, ports, cfg.simulation.step_s, nominal, REWIRING[plant]),
                             inputs=spec.external_inputs(cfg), sums=ports.sums) for _ in range(2))
    assert first.layout == second.layout
    np.testing.assert_array_equal(first.initial_params(), second.initial_params())
    for a, b in zip(first.initial_state(), second.initial_state(), strict=True):
        np.testing.assert_array_equal(a, b)


def test_attach_refuses_an_effect_that_does_not_apply(fe):
    spec, cfg = fe
    with pytest.raises(DiagramError, match="does not apply to plant 'finger_extensor'"):
        attach(spec.name, spec.ports(cfg), cfg.simulation.step_s, spec.build(cfg),
               [("sma_hysteresis", {"width_c": 5.0})])


def _out(part_cls, u, p, xd=None):
    y = np.zeros(1)
    part_cls.output(0.0, np.zeros(0), np.zeros(1) if xd is None else xd, np.asarray(u, float),
                    np.asarray(p, float), y)
    return y[0]


def test_transport_delay_returns_the_input_from_delay_steps_ago():
    xd = np.arange(1.0, DELAY_SLOTS + 1.0)  # xd[i] = input i+1 steps ago
    assert _out(TransportDelay, [0.0], [0.0, 0.001], xd) == 0.0
    assert _out(TransportDelay, [0.0], [0.003, 0.001], xd) == pytest.approx(3.0)
    assert _out(TransportDelay, [0.0], [0.0025, 0.001], xd) == pytest.approx(2.5)


def test_backlash_holds_until_the_gap_is_taken_up():
    assert _out(Backlash, [0.01], [0.04], np.array([0.0])) == 0.0  # inside the play
    assert _out(Backlash, [0.05], [0.04], np.array([0.0])) == pytest.approx(0.03)  # dragged along
    assert _out(Backlash, [0.05], [0.0], np.array([0.0])) == 0.05  # zero width: a wire


def test_contact_pushes_back_past_the_contact_angle_and_never_pulls():
    assert _out(ContactSpringDamper, [0.3, 1.0], [2.0, 0.1, 0.5]) == 0.0
    assert _out(ContactSpringDamper, [0.7, 0.0], [2.0, 0.1, 0.5]) == pytest.approx(-0.4)
    assert _out(ContactSpringDamper, [0.6, -5.0], [2.0, 0.1, 0.5]) == 0.0  # leaving fast: no pull


SHORT = {"finger_extensor": ("step", 0.6), "sma_exoskeleton": ("pwm-step", 1.5), "tcp_finger": ("pulse", 2.0)}


@pytest.mark.parametrize("plant", sorted(SHORT))
def test_every_applicable_effect_at_zero_magnitude_leaves_the_nominal_response_unchanged(plant):
    from rehab_hil.plants import run_scenario

    spec = get_plant(plant)
    cfg = load_config(CONFIGS / f"{plant}.toml")
    effects = applicable(spec.ports(cfg))
    assert {"coulomb_friction", "viscous_friction", "backlash", "time_delay", "contact_spring_damper"} <= {
        e.name for e in effects}  # the mechanical effects attach to every plant with an axis and an encoder
    scenario, duration = SHORT[plant]
    nominal = run_scenario(spec, cfg, spec.scenarios[scenario](cfg, duration))
    off = [EffectSpec(name=e.name, params=e.disabled()) for e in effects]
    res = run_scenario(spec, cfg.model_copy(update={"effects": off}), spec.scenarios[scenario](cfg, duration))
    for name in spec.outputs:
        if name in nominal.signals:
            np.testing.assert_allclose(res[name], nominal[name], rtol=0, atol=1e-9, err_msg=name)


def _kernel_out(part_cls, u, **params):
    y = np.zeros(1)
    part_cls.output(0.0, np.zeros(0), np.zeros(0), np.array(u, float), np.array(list(params.values()), float), y)
    return float(y[0])


def test_actuator_dead_zone_removes_the_band_on_both_signs():
    from rehab_hil.models.effect_parts import ActuatorDeadZone

    w = dict(width_duty=0.04, scale=24.0)  # 0.96 V of a 24 V H-bridge
    assert [_kernel_out(ActuatorDeadZone, [u], **w) for u in (-5.0, -0.9, 0.0, 0.9, 5.0)] == pytest.approx(
        [-4.04, 0.0, 0.0, 0.0, 4.04])
    assert _kernel_out(ActuatorDeadZone, [3.0], width_duty=0.0, scale=24.0) == 3.0  # off: a wire
    assert {e.name for e in _applicable("finger_extensor")} >= {"actuator_dead_zone", "sensor_gain_offset"}
    assert EFFECTS["actuator_dead_zone"].needs == "actuator" and EFFECTS["sensor_gain_offset"].needs == "adc"


def test_sensor_gain_offset_forward_and_inverse():
    from rehab_hil.models.effect_parts import SensorGainOffset

    p = dict(gain_error_fraction=0.1, offset_counts=20.0, counts_per_unit=100.0)
    assert _kernel_out(SensorGainOffset, [2.0], **p, invert=0.0) == pytest.approx(1.1 * 2.0 + 0.2)
    assert _kernel_out(SensorGainOffset, [1.1 * 2.0 + 0.2], **p, invert=1.0) == pytest.approx(2.0)


def test_sensor_gain_on_a_recorded_input_feeds_the_model_the_true_value(fe):
    """The Finger Extensor's torque sensor measures an input (patient_torque_nm): the effect sits
    between the recorded column and the plant, and gives the plant the true torque."""
    spec, cfg = fe
    ports = spec.ports(cfg)
    parts = attach(spec.name, ports, 0.001, spec.build(cfg),
                   [("sensor_gain_offset", {"gain_error_fraction": 0.25, "offset_counts": 0.0})])
    readers = [p for p in parts if any(s == "patient_torque_nm" for t in p.connections.values() for s, _ in t)]
    assert [p.name for p in readers] == ["effect_sensor_gain_offset"]
    assert parts[-1].param_values[-1] == 1.0  # invert


def test_sensor_gain_on_a_modelled_signal_takes_its_name_over():
    """On the SMA exoskeleton the Flexiforce reads the model's contact force: the plant's producer is
    renamed ``contact_force_n_true`` and the effect produces the recorded ``contact_force_n``."""
    spec, cfg = get_plant("sma_exoskeleton"), load_config(CONFIGS / "sma_exoskeleton.toml")
    parts = attach(spec.name, spec.ports(cfg), 0.001, spec.build(cfg),
                   [("sensor_gain_offset", {"gain_error_fraction": -0.1}), ("viscous_friction", {})])
    producers = [p.name for p in parts if "contact_force_n" in p.signal_names]
    assert producers == ["effect_sensor_gain_offset"]  # attached last although listed first
    assert any("contact_force_n_true" in p.signal_names for p in parts if p.name == "contact")
    assert parts[-1].connections["u"] == [("contact_force_n_true", 1.0)]


def _bench():
    import importlib.util

    spec_ = importlib.util.spec_from_file_location("bench_discrepancy", CONFIGS.parent / "bench" / "discrepancy.py")
    bench = importlib.util.module_from_spec(spec_)
    spec_.loader.exec_module(bench)
    return bench


@pytest.mark.slow
def test_sensor_gain_offset_is_found_on_an_independent_record(fe):
    from rehab_hil.discrepancy.workflow import Options, find_missing_effects

    _spec, cfg = fe
    true = {"gain_error_fraction": -0.2, "offset_counts": -20.0}  # torque sensor 20 % low, zero 0.2 N m off
    rec = _bench().fe_record({"sensor_gain_offset": true}, {}, 12, duration_s=10.0)
    res = find_missing_effects(cfg, rec, "sensor.csv", options=Options(max_effects=1))
    assert res.named == ["sensor_gain_offset"], res.conclusion
    fit = res.chosen[0].params
    assert fit["gain_error_fraction"] == pytest.approx(true["gain_error_fraction"], abs=0.05)
    assert fit["offset_counts"] == pytest.approx(true["offset_counts"], abs=3.0)


@pytest.mark.slow
def test_actuator_dead_zone_is_found_on_an_independent_record(fe):
    from rehab_hil.discrepancy.workflow import Options, find_missing_effects

    _spec, cfg = fe
    rec = _bench().fe_record({"actuator_dead_zone": {"width_duty": 1.0 / 24}}, {}, 11, duration_s=10.0)
    res = find_missing_effects(cfg, rec, "dz.csv", options=Options(max_effects=1))
    assert res.named == ["actuator_dead_zone"], res.conclusion
    assert res.chosen[0].params["width_duty"] * 24 == pytest.approx(1.0, rel=0.15)
