"""The patient's parts, each alone in a diagram: fatigue at the three-compartment model's rate, the
stretch reflex above its threshold after its delay, slacking, the passive finger, the task's cue."""

from __future__ import annotations

import math

import numpy as np
import pytest

from rehab_hil.controllers import Reference
from rehab_hil.loading import load_config
from rehab_hil.models.system import Diagram
from rehab_hil.patient.attach import _cue
from rehab_hil.patient.parts import PassiveFinger, SlackingEffort, StretchReflex, ThreeCompartmentFatigue
from tests.conftest import CONFIGS

DT = 0.001


def _run(part, inputs, n, outputs):
    system = Diagram([part], inputs=tuple(inputs)).compile(DT, 1)
    return system.simulate(n, inputs, outputs=list(outputs))


def test_fatigue_lowers_the_capacity_at_the_three_compartment_models_rate():
    # Xia & Frey Law 2008 at a sustained maximal load (TL = 1): once the resting pool is recruited
    # (L_D = 10/s: a few tenths of a second), M_A = 1 - M_F and dM_F/dt = F (1 - M_F) - R M_F, so the
    # capacity left is 1 - F/(F+R) (1 - exp(-(F+R) t))
    f, r = 0.05, 0.00134
    part = ThreeCompartmentFatigue("fatigue", x0=[0.0, 0.0], fatigue_per_s=f, recovery_per_s=r,
                                   rest_recovery_factor=9.1, develop_per_s=10.0, relax_per_s=10.0,
                                   capacity_pos_nm=1.0, capacity_neg_nm=0.5)
    n = 120_000
    res = _run(part, {"demand_nm": 1.0}, n, ["capacity_fraction", "torque_nm"])
    for t_s in (10.0, 30.0, 60.0, 119.0):
        k = int(t_s / DT)
        expected = 1.0 - f / (f + r) * (1.0 - math.exp(-(f + r) * t_s))
        assert res["capacity_fraction"][k] == pytest.approx(expected, abs=0.01)
    # the torque the patient can hold falls with it: a demand of the full capacity gets less and less
    assert res["torque_nm"][int(60 / DT)] == pytest.approx(res["capacity_fraction"][int(60 / DT)], abs=0.01)
    assert res["torque_nm"][-1] < 0.5


def test_no_fatigue_rate_keeps_the_full_capacity_and_the_demand_is_clamped_per_direction():
    part = ThreeCompartmentFatigue("fatigue", x0=[0.0, 0.0], fatigue_per_s=0.0, recovery_per_s=0.0,
                                   rest_recovery_factor=1.0, develop_per_s=10.0, relax_per_s=10.0,
                                   capacity_pos_nm=1.0, capacity_neg_nm=0.25)
    res = _run(part, {"demand_nm": np.full(5000, -2.0)}, 5000, ["capacity_fraction", "torque_nm"])
    assert res["capacity_fraction"][-1] == 1.0
    assert res["torque_nm"][-1] == pytest.approx(-0.25, abs=1e-3)  # the weaker direction's capacity


def _reflex(velocity):
    part = StretchReflex("reflex", flexion_sign=1.0, threshold_rad_s=0.5, gain_nm_s_per_rad=0.2, delay_s=0.04,
                         step_s=DT)
    return _run(part, {"velocity_rad_s": velocity}, len(velocity), ["torque_nm"])


def test_spasticity_torque_appears_only_above_the_velocity_threshold_after_its_delay():
    n, onset = 400, 100
    fast = np.zeros(n)
    fast[onset:] = -1.5  # extension at 1.5 rad/s: 1 rad/s above the threshold
    tau = _reflex(fast)["torque_nm"]
    first = int(np.flatnonzero(tau > 0)[0])
    assert first == onset + 40  # 40 ms later, to the sample
    assert tau[first:] == pytest.approx(0.2 * 1.0)  # flexing, gain x (speed - threshold)
    slow = np.where(np.arange(n) >= onset, -0.45, 0.0)  # below the threshold
    assert not np.any(_reflex(slow)["torque_nm"])
    flexing = np.where(np.arange(n) >= onset, 1.5, 0.0)  # the flexors shorten: no stretch, no reflex
    assert not np.any(_reflex(flexing)["torque_nm"])


def test_slacking_effort_decays_with_its_time_constant_while_the_error_is_zero():
    part = SlackingEffort("slack", x0=[1.0], slack_time_s=2.0, error_gain_per_rad_s=0.5, effort_min=0.0)
    res = _run(part, {"cue_rad": 0.3, "angle_rad": 0.3}, 4001, ["effort"])
    assert res["effort"][2000] == pytest.approx(math.exp(-1.0), rel=0.01)
    grows = _run(SlackingEffort("slack", x0=[0.2], slack_time_s=2.0, error_gain_per_rad_s=0.5, effort_min=0.0),
                 {"cue_rad": 1.0, "angle_rad": 0.0}, 4001, ["effort"])
    assert grows["effort"][-1] > 0.5  # a large error brings the effort back
    off = _run(SlackingEffort("slack", x0=[1.0], slack_time_s=0.0, error_gain_per_rad_s=0.0, effort_min=1.0),
               {"cue_rad": 0.0, "angle_rad": 0.0}, 1000, ["effort"])
    assert np.all(off["effort"] == 1.0)


def test_the_passive_finger_is_zero_at_rest_and_stiffer_toward_its_ends():
    part = PassiveFinger("finger", flexion_sign=1.0, offset_rad=0.0, rest_flexion_rad=0.6, extension_scale_nm=0.01,
                         extension_shape_per_rad=3.0, flexion_scale_nm=0.01, flexion_shape_per_rad=3.0,
                         damping_nm_s_per_rad=0.0)
    angles = np.array([0.0, 0.05, 0.55, 0.6, 0.65, 1.5, 1.55])
    tau = _run(part, {"angle_rad": angles, "velocity_rad_s": 0.0}, len(angles), ["torque_nm"])["torque_nm"]
    assert tau[3] == pytest.approx(0.0, abs=1e-12)
    assert tau[0] > 0 > tau[-1]  # pushes back toward rest from both ends
    mid = (tau[2] - tau[4]) / 0.1
    near_end = (tau[5] - tau[6]) / 0.05
    assert near_end > 5 * mid  # 5-20x stiffer near the ends (Kuo & Deshpande 2012)


def test_the_cue_is_the_hosts_reference_seen_a_reaction_time_late():
    cfg = load_config(CONFIGS / "finger_extensor.toml")
    ref = Reference.session(cfg)
    t = np.arange(0.0, 2 * ref.period_s, DT)
    cue = _run(_cue(cfg, 0.2), {"session_time_s": t}, len(t), ["patient_cue_rad"])["patient_cue_rad"]
    assert np.degrees(cue) == pytest.approx(ref.values(t - 0.2), abs=1e-9)


def test_a_patient_rides_on_a_rig_whose_plant_changes_mid_session(tmp_path):
    # the patient's parts are appended to the plant's: a scheduled change still moves its own parameter
    from rehab_hil.devices.patient_plant import patient_plant
    from rehab_hil.plants import get_plant
    from rehab_hil.testing import config_with_changes

    path = config_with_changes(CONFIGS / "finger_extensor.toml", tmp_path / "sag.toml",
                               changes=[{"key": "iris.spring_nm_per_rad", "scale": 2.0, "start_s": 0.01}])
    cfg = load_config(path)
    plant = patient_plant(cfg, get_plant(cfg.plant).device(cfg), CONFIGS.parent / "profiles/sim/capable.toml")
    item = plant.schedule.items[0]
    before = plant.stepper.params[item.param_index]
    for _ in range(20):
        plant.tick([0, 0], 0)
    assert plant.stepper.params[item.param_index] == pytest.approx(2.0 * before)
    names = plant.system.diagram.param_names
    assert {names[i] for i in np.atleast_1d(item.param_index)} == {"spring.stiffness_nm_per_rad"}


def test_the_voluntary_loop_closes_a_steady_shortfall_within_its_integral_limit():
    from rehab_hil.patient.parts import VoluntaryDemand

    part = VoluntaryDemand("voluntary", kp_nm_per_rad=1.0, kd_nm_s_per_rad=0.0, ki_nm_per_rad_s=2.0,
                           integral_limit_rad_s=0.2)
    res = _run(part, {"cue_rad": 1.0, "angle_rad": 0.9, "velocity_rad_s": 0.0, "effort": 1.0}, 4000, ["demand_nm"])
    d = res["demand_nm"]
    assert d[0] == pytest.approx(0.1)  # the proportional part at once
    assert d[1000] == pytest.approx(0.1 + 2.0 * 0.1 * 1.0, abs=1e-3)  # the integral of 0.1 rad over 1 s
    assert d[-1] == pytest.approx(0.1 + 2.0 * 0.2, abs=1e-3)  # held at its limit
