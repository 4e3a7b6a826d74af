"""Where a patient's passive finger rests on each plant's axis: on an MCP axis (the SMA exoskeleton,
the TCP finger) at the axis's zero, the device fitted and homed at the relaxed posture; on the
Finger Extensor's iris straight at the session's open angle, so a flexed rest pulls there."""

from __future__ import annotations

import math

import numpy as np
import pytest

from rehab_hil.loading import load_config
from rehab_hil.patient.attach import patient_parts
from rehab_hil.patient.parts import PassiveFinger
from rehab_hil.patient.profile import load_patient
from rehab_hil.plants import get_plant
from rehab_hil.testing import CONFIGS

WEAK = CONFIGS.parent / "profiles" / "sim" / "weak.toml"


def passive_torque_nm(config: str, angle_rad: float) -> float:
    cfg = load_config(CONFIGS / config)
    parts = patient_parts(get_plant(cfg.plant).ports(cfg), cfg, load_patient(WEAK))
    (passive,) = [p for p in parts if isinstance(p, PassiveFinger)]
    y = np.zeros(1)
    PassiveFinger.output(0.0, np.zeros(0), np.zeros(0), np.array([angle_rad, 0.0]), passive.param_values, y)
    return float(y[0])


@pytest.mark.parametrize("config", ["sma_exoskeleton.toml", "tcp_finger.toml"])
def test_on_an_mcp_axis_the_relaxed_finger_rests_at_the_axis_zero_and_resists_the_bend(config):
    assert passive_torque_nm(config, 0.0) == pytest.approx(0.0, abs=1e-12)
    assert passive_torque_nm(config, math.radians(30.0)) < 0.0  # bent past its rest: it pulls back


def test_on_the_finger_extensors_iris_a_flexed_rest_pulls_the_opened_finger_closed():
    cfg = load_config(CONFIGS / "finger_extensor.toml")
    straight = math.radians(cfg.rig.session.open_deg)  # the iris angle where the finger is straight
    assert passive_torque_nm("finger_extensor.toml", straight) < -0.1  # toward flexion: the iris closing
