"""The fastest mode of a compiled diagram and the RK4 substeps it needs: a mass on a spring and a
damper, whose eigenvalues are known, and the TCP finger with a simulated patient on it."""

from __future__ import annotations

import math

import numpy as np
import pytest

from rehab_hil.models.mechanics import RotaryInertia, TorsionSpring, ViscousFriction
from rehab_hil.models.stability import RK4_LIMIT, fastest_mode, substeps_for
from rehab_hil.models.system import Diagram


def oscillator(k: float, b: float, inertia: float):
    parts = [RotaryInertia("mass", inertia_kg_m2=inertia),
             TorsionSpring("spring", stiffness_nm_per_rad=k, rest_angle_rad=0.0),
             ViscousFriction("damper", damping_nm_s_per_rad=b)]
    return Diagram(parts, inputs=(), sums=("torque_nm",)).compile(0.001, 1)


@pytest.mark.parametrize(("k", "b"), [(3.0, 0.0), (0.0, 0.05), (3.0, 0.05)])
def test_the_fastest_mode_of_a_damped_mass_on_a_spring_is_its_largest_eigenvalue(k, b):
    inertia = 2.5e-5
    lam = np.roots([inertia, b, k])
    system = oscillator(k, b, inertia)
    assert fastest_mode(system, np.zeros(1)) == pytest.approx(float(np.max(np.abs(lam))), rel=1e-3)


def test_the_substeps_keep_lambda_h_within_the_rk4_limit():
    assert substeps_for(500.0, 0.001) == 1
    assert substeps_for(8000.0, 0.001) == math.ceil(8.0 / RK4_LIMIT) == 4
    assert substeps_for(10.0, 0.001, at_least=3) == 3


def test_a_capable_patient_on_the_tcp_finger_takes_the_substeps_that_hold_it_at_the_cue():
    """With one RK4 step per ms the patient's loop on the finger's grams rests off the 0 deg cue the
    patient pushes toward (0.6 deg, a third of the task; 7.4 deg with a flexed rest at the zero);
    with the substeps chosen it holds the cue."""
    from rehab_hil.loading import load_config
    from rehab_hil.patient.attach import with_patient
    from rehab_hil.patient.profile import load_patient
    from rehab_hil.plants import get_plant
    from rehab_hil.testing import CONFIGS

    cfg = load_config(CONFIGS / "tcp_finger.toml")
    bare = get_plant(cfg.plant).device(cfg)
    b = with_patient(bare, cfg, load_patient(CONFIGS.parent / "profiles" / "sim" / "capable.toml"))
    assert bare.substeps == 1 and b.substeps == 4
    inputs = (*b.duty_inputs, *b.constant_inputs)
    diagram = Diagram(b.parts, inputs=inputs, sums=b.sums)
    n = 3000  # 3 s of the first closed hold: the cue at 0 deg
    angles = {}
    for sub in (1, b.substeps):
        given = {**b.constant_inputs, "session_time_s": np.arange(n) * b.step_s}
        res = diagram.compile(b.step_s, sub).simulate(n, given, outputs=["theta_mcp_rad"])
        angles[sub] = math.degrees(res["theta_mcp_rad"][-1])
    assert abs(angles[1]) > 0.3 and abs(angles[b.substeps]) < 0.05
