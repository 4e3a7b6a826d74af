"""Plant registration: a config's [[effects]] reach both the offline build and the rig binding; each
plant declares the signals its parts sum onto, and its diagram is built with them."""

from __future__ import annotations

from pathlib import Path

import pytest

from rehab_hil.effects import applicable, attach
from rehab_hil.loading import load_config
from rehab_hil.models.sensors import Gain
from rehab_hil.models.system import Diagram, DiagramError
from rehab_hil.plants import compose, get_plant

CONFIGS = Path(__file__).resolve().parents[2] / "configs"
EFFECT = '\n[[effects]]\nname = "coulomb_friction"\nparams = { level_nm = 0.03 }\n'


@pytest.mark.parametrize("plant", ["finger_extensor"])
def test_config_effects_reach_the_build_and_the_simulated_rig(tmp_path, plant):
    path = tmp_path / f"{plant}.toml"
    path.write_text((CONFIGS / f"{plant}.toml").read_text() + EFFECT)
    cfg = load_config(path)
    spec = get_plant(plant)
    plain = {p.name for p in spec.device(load_config(CONFIGS / f"{plant}.toml")).parts}
    built = {p.name for p in compose(spec, cfg)}
    rig = {p.name for p in spec.device(cfg).parts}
    added = built - plain
    assert added, "the effect was not attached to the build"
    assert added <= rig, "the simulated rig's binding lost the config's effects"


PLANTS = ["finger_extensor", "sma_exoskeleton", "tcp_finger"]


def _producers(parts) -> dict[str, list[str]]:
    out: dict[str, list[str]] = {}
    for p in parts:
        for s in p.signal_names:
            out.setdefault(s, []).append(p.name)
    return out


@pytest.mark.parametrize("plant", PLANTS)
def test_a_plant_declares_exactly_the_signals_its_parts_sum_onto(plant):
    """Every joint's torque sum is declared (not only the primary axis's), and nothing else is."""
    spec = get_plant(plant)
    cfg = load_config(CONFIGS / f"{plant}.toml")
    several = {s for s, who in _producers(spec.build(cfg)).items() if len(who) > 1}
    assert several == set(spec.ports(cfg).sums)
    assert spec.device(cfg).sums == spec.ports(cfg).sums  # the simulated rig builds with the same sums


@pytest.mark.parametrize("plant", PLANTS)
def test_without_its_sums_a_plant_diagram_is_refused_naming_the_summed_signal(plant):
    spec = get_plant(plant)
    cfg = load_config(CONFIGS / f"{plant}.toml")
    with pytest.raises(DiagramError) as err:
        Diagram(spec.build(cfg), inputs=spec.external_inputs(cfg))
    assert any(f"signal {s!r} is produced by parts " in str(err.value) for s in spec.ports(cfg).sums), err.value


@pytest.mark.parametrize("plant", PLANTS)
def test_every_applicable_effect_attaches_within_the_declared_sums(plant):
    """Effects that sum onto an axis torque use a declared signal; their own outputs are unique."""
    spec = get_plant(plant)
    cfg = load_config(CONFIGS / f"{plant}.toml")
    ports = spec.ports(cfg)
    effects = [(e.name, e.disabled()) for e in applicable(ports)]
    parts = attach(spec.name, ports, spec.step(cfg)[0], spec.build(cfg), effects)
    d = Diagram(parts, inputs=spec.external_inputs(cfg), sums=ports.sums)
    several = {s for s, slots in d.producers.items() if len(slots) > 1}
    assert several <= set(ports.sums)
    assert len(d.producers[ports.axes[0].torque]) > len(_producers(spec.build(cfg))[ports.axes[0].torque])


def test_the_diagram_helper_adds_parts_inputs_and_sums_to_the_composed_plant():
    spec = get_plant("finger_extensor")
    cfg = load_config(CONFIGS / "finger_extensor.toml")
    d = spec.diagram(cfg)
    assert [p.name for p in d.parts] == [p.name for p in compose(spec, cfg)]
    assert d.sums == spec.ports(cfg).sums
    # a feedforward and a feedback effort on one command: legal only as a declared extra sum
    ff = Gain("feedforward", connect={"u": "reference_v"}, rename={"y": "motor_voltage_v"}, gain=1.0)
    fb = Gain("feedback", connect={"u": "iris_angle_deg"}, rename={"y": "motor_voltage_v"}, gain=-0.1)
    with pytest.raises(DiagramError, match="signal 'motor_voltage_v' is produced by parts 'feedforward' and "
                                           "'feedback'"):
        spec.diagram(cfg, [ff, fb], extra_inputs=("reference_v",))
    both = spec.diagram(cfg, [ff, fb], extra_inputs=("reference_v",), extra_sums=("motor_voltage_v",))
    assert "reference_v" in both.input_names and "motor_voltage_v" not in both.input_names
    assert len(both.producers["motor_voltage_v"]) == 2
