"""One thermal model of each heated actuator (issue 47 item 1), without a session: the safety's estimate is
the plant's own model; the twin's values only tighten it (a warmer room, less convection, a higher supply,
at the strict end of their interval), never loosen it, and never lower the temperature it reads; the
controller's observer follows it; a config can hold no second model."""

from __future__ import annotations

import pickle
from pathlib import Path

import numpy as np
import pytest

from rehab_hil.config import ConfigError
from rehab_hil.control.thermal import ModalThermal
from rehab_hil.controllers import build_controller
from rehab_hil.loading import load_config
from rehab_hil.loop.controllers import Command, ControllerRuntime
from rehab_hil.loop.estimation import State
from rehab_hil.loop.process import _act
from rehab_hil.loop.thermal import SafetyThermal, ThermalTightening
from rehab_hil.models.sma_thermal import steady_temperature_c as eq12_steady_c
from rehab_hil.plants.changes import with_values
from rehab_hil.plants.registry import get_plant, run_scenario
from rehab_hil.plants.thermal import ActuatorThermal, safety_thermal, steady_temperature_c
from rehab_hil.service import assembly
from rehab_hil.service.features.safety_thermal import Tightener, hotter_direction
from rehab_hil.testing import CONFIGS

SMA, TCP, FE = (CONFIGS / f"{p}.toml" for p in ("sma_exoskeleton", "tcp_finger", "finger_extensor"))
ROOM, DRAFT, SUPPLY = "sma.ambient_c", "sma.h1_w_per_m2_c", "drive.supply_voltage_v"


@pytest.fixture(scope="module")
def sma():
    return load_config(SMA)


def test_the_safety_estimates_with_the_plants_own_model_where_the_plant_has_one(sma) -> None:
    cfg = sma
    sup = assembly.build_supervisor(cfg, get_plant(cfg.plant).device(cfg))
    assert isinstance(sup.thermal, ActuatorThermal) and sup.thermal.temperature == "sma_temperature_c"
    res = run_scenario(get_plant(cfg.plant), cfg, get_plant(cfg.plant).scenarios["pwm-step"](cfg, 8.0))
    est = [sup.thermal.step(d, cfg.simulation.step_s) for d in res["pwm_duty"]]
    # the plant's simulated wire (what a simulated rig runs) and the supervisor's estimate: the same model
    np.testing.assert_allclose(est[:-1], res["sma_temperature_c"][1:], atol=0.01)
    s = cfg.sma
    level = eq12_steady_c(1.0, cfg.drive.supply_voltage_v, s.radius_m, s.length_m, s.resistivity_ohm_m,
                          s.h1_w_per_m2_c, s.h2_w_per_m2_c3, s.ambient_c)  # seed 000 eq 12's own root
    assert steady_temperature_c(ActuatorThermal.of(cfg), 1.0) == pytest.approx(level, abs=0.01)
    assert isinstance(safety_thermal(load_config(TCP)), ActuatorThermal)
    assert isinstance(safety_thermal(load_config(FE)), ModalThermal)  # its winding: the host's own [rig.thermal]


def test_a_second_thermal_model_in_the_config_is_refused_in_one_line(tmp_path: Path) -> None:
    text = SMA.read_text()
    twice = tmp_path / "twice.toml"
    twice.write_text(text + "\n[rig.thermal]\nambient_c = 23.0\nrise_at_full_duty_c = 110.0\ntime_constant_s = 1.0\n")
    with pytest.raises(ConfigError) as e:
        load_config(twice)
    assert e.value.key == "rig.thermal.rise_at_full_duty_c" and "sma_temperature_c" in str(e.value)
    assert "\n" not in str(e.value)
    cooler = tmp_path / "cooler.toml"  # a simulated rig's file: its wire cannot reach the limit, and that is no error
    cooler.write_text(text.replace("supply_voltage_v = 32.0", "supply_voltage_v = 28.8"))
    assert steady_temperature_c(ActuatorThermal.of(load_config(cooler)), 1.0) < 132.8
    half = tmp_path / "half.toml"
    half.write_text(FE.read_text().replace("time_constant_s = 120.0\n", ""))
    with pytest.raises(ConfigError, match="time_constant_s is missing"):
        load_config(half)


def test_which_way_is_stricter_is_the_models_answer(sma) -> None:
    assert hotter_direction(sma, ROOM) == 1 and hotter_direction(sma, DRAFT) == -1
    assert hotter_direction(sma, SUPPLY) == 1


def est(value: float, ci: float) -> dict[str, float]:
    return {"value": value, "ci95": ci}


def test_only_the_stricter_end_of_a_stricter_estimate_is_taken_never_a_looser_one(sma) -> None:
    t = Tightener(sma, [ROOM, DRAFT, SUPPLY], 0.001)
    warm = {ROOM: est(29.98, 0.02), DRAFT: est(330.0, 0.5), SUPPLY: est(31.0, 0.01)}  # warmer, a draft, a sag
    assert t.stricter(warm, list(warm)) == {ROOM: pytest.approx(30.0)}  # the room only, at its warm end
    still = {ROOM: est(18.0, 0.1), DRAFT: est(240.0, 1.0), SUPPLY: est(33.0, 0.2)}
    assert t.stricter(still, list(still)) == {DRAFT: pytest.approx(239.0), SUPPLY: pytest.approx(33.2)}
    t.values.update({ROOM: 30.0})
    assert t.stricter({ROOM: est(29.0, 0.5)}, [ROOM]) == {}  # below what is in force: not a tightening


def test_a_tightening_gives_the_state_the_drive_so_far_would_have_reached_and_never_reads_cooler(sma) -> None:
    t = Tightener(sma, [ROOM], 0.001)
    for k in range(6000):  # 3 s at duty 1, then 3 s off
        t.record(k * 0.001, 1.0 if k < 3000 else 0.0)
    change = t.tightening(6.0, {ROOM: 30.0})
    assert change.values == {ROOM: 30.0} and change.previous == {ROOM: 23.0} and t.values[ROOM] == 30.0
    warm = ActuatorThermal.of(with_values(sma, {ROOM: 30.0}))
    for k in range(6000):
        warm.step(1.0 if k < 3000 else 0.0, 0.001)
    model = ActuatorThermal.of(sma)
    for k in range(6000):
        model.step(1.0 if k < 3000 else 0.0, 0.001)
    safety = SafetyThermal(model)
    assert safety.tighten(6.0, change)
    assert model.temperature_c == pytest.approx(warm.temperature_c, abs=0.05)  # as if it had known all along
    cooler = ThermalTightening(7.0, {ROOM: 31.0}, {ROOM: 30.0}, change.params, change.constants, change.duty_scale,
                               np.array([-5.0]))
    before = model.temperature_c
    assert safety.tighten(7.0, cooler) and model.temperature_c == pytest.approx(before)
    assert [c["values"] for c in safety.changes] == [{ROOM: 30.0}, {ROOM: 31.0}]
    assert pickle.loads(pickle.dumps(change)).values == change.values  # what the mailbox carries


def test_a_tightened_estimate_trips_sooner_and_through_a_loop_message(sma) -> None:
    def seconds_to_trip(change: ThermalTightening | None) -> float:
        sup = assembly.build_supervisor(sma, get_plant(sma.plant).device(sma))
        loop = type("Loop", (), {"tighten_thermal": lambda self, c: sup.tighten_thermal(0.0, c)})()
        if change is not None:
            _act(loop, ("thermal", change))  # what a loop process does with the message
        for k in range(20000):
            sup.admit(k * 0.001, Command((1.0, 0.0), 0, True))
            if sup.tripped:
                assert sup.events[0].reason == "temperature"
                return k * 0.001
        return np.inf

    t = Tightener(sma, [ROOM], 0.001)
    nominal, warm = seconds_to_trip(None), seconds_to_trip(t.tightening(0.0, {ROOM: 35.0}))
    assert nominal == pytest.approx(1.63, abs=0.02) and warm < nominal - 0.3


def test_the_controllers_ceiling_acts_on_the_supervisors_estimate(sma) -> None:
    runtime = ControllerRuntime(build_controller(sma, "pid", check=False))
    sup = assembly.build_supervisor(sma, get_plant(sma.plant).device(sma))
    assert runtime.follow_thermal(sup)
    far = State(0.0, -0.5, 0.0, {})  # 29 deg below the reference: the PID asks for all it may
    assert runtime(0.0, far).duty[0] > 0.5
    sup.thermal.set_state(np.array([103.0]))  # the supervisor's estimate at the budget (the observer's is 23 C)
    assert runtime(0.001, far).duty[0] == 0.0
    sup.thermal.set_state(np.array([60.0]))
    assert runtime(0.002, far).duty[0] > 0.5
    assert pickle.loads(pickle.dumps(runtime))._follow is None  # a loop process wires it again
