"""The part/diagram framework: wiring, summing, ordering, errors, and the integrator's accuracy."""

from __future__ import annotations

import math

import numpy as np
import pytest

from rehab_hil.models.mechanics import RotaryInertia, TorsionSpring, ViscousFriction
from rehab_hil.models.sensors import Gain
from rehab_hil.models.system import Diagram, DiagramError


def oscillator(k=4.0, b=0.0, j=1.0, x0=(1.0, 0.0)):
    return [
        RotaryInertia("mass", connect={"torque_nm": "torque_nm"}, x0=list(x0), inertia_kg_m2=j),
        TorsionSpring("spring", rename={"torque_nm": "torque_nm"}, stiffness_nm_per_rad=k, rest_angle_rad=0.0),
        ViscousFriction("damper", rename={"torque_nm": "torque_nm"}, damping_nm_s_per_rad=b),
    ]


def test_rk4_matches_the_analytic_oscillator_to_fourth_order():
    sys = Diagram(oscillator()).compile(dt=1e-3)
    res = sys.simulate(5000, outputs=["angle_rad"])
    exact = np.cos(2.0 * res.t)
    assert np.max(np.abs(res["angle_rad"] - exact)) < 1e-9


def test_substeps_refine_a_coarse_step():
    d = Diagram(oscillator())
    coarse = d.compile(dt=0.05).simulate(200, outputs=["angle_rad"])
    fine = d.compile(dt=0.05, substeps=8).simulate(200, outputs=["angle_rad"])
    exact = np.cos(2.0 * coarse.t)
    err_c = np.max(np.abs(coarse["angle_rad"] - exact))
    err_f = np.max(np.abs(fine["angle_rad"] - exact))
    assert err_f < err_c / 1000  # RK4: error ~ h^4, 8x smaller step -> ~4096x smaller error


def test_outputs_with_one_name_are_summed_and_unproduced_inputs_are_external():
    parts = [
        Gain("a", connect={"u": "x_in"}, rename={"y": "total"}, gain=2.0),
        Gain("b", connect={"u": "x_in"}, rename={"y": "total"}, gain=3.0),
        Gain("c", connect={"u": [("total", 1.0), ("other_in", -1.0)]}, rename={"y": "out"}, gain=1.0),
    ]
    d = Diagram(parts)
    assert set(d.input_names) == {"x_in", "other_in"}
    res = d.compile(0.01).simulate(3, inputs={"x_in": 1.0, "other_in": 0.5}, outputs=["total", "out"])
    assert np.allclose(res["total"], 5.0)
    assert np.allclose(res["out"], 4.5)


def test_feedthrough_parts_are_evaluated_after_their_sources():
    # declared in reverse order: c reads b reads a
    parts = [
        Gain("c", connect={"u": "sb"}, rename={"y": "sc"}, gain=10.0),
        Gain("b", connect={"u": "sa"}, rename={"y": "sb"}, gain=10.0),
        Gain("a", connect={"u": "x_in"}, rename={"y": "sa"}, gain=10.0),
    ]
    res = Diagram(parts).compile(0.01).simulate(2, inputs={"x_in": 1.0}, outputs=["sc"])
    assert np.allclose(res["sc"], 1000.0)


def test_algebraic_loop_is_refused_with_the_parts_named():
    parts = [Gain("a", connect={"u": "sb"}, rename={"y": "sa"}, gain=1.0),
             Gain("b", connect={"u": "sa"}, rename={"y": "sb"}, gain=1.0)]
    with pytest.raises(DiagramError, match="algebraic loop"):
        Diagram(parts)


@pytest.mark.parametrize(
    ("make", "fragment"),
    [
        (lambda: Gain("g", gain=1.0, bogus=2.0), "unknown parameters"),
        (lambda: Gain("g"), "missing parameters"),
        (lambda: Gain("g", connect={"nope": "x"}, gain=1.0), "has no inputs"),
        (lambda: Gain("g", rename={"nope": "x"}, gain=1.0), "has no outputs"),
        (lambda: Diagram([Gain("g", gain=1.0), Gain("g", gain=2.0)]), "duplicate part names"),
    ],
)
def test_wiring_mistakes_are_refused(make, fragment):
    with pytest.raises(DiagramError, match=fragment):
        make()


def test_params_vector_changes_behaviour_without_recompiling():
    d = Diagram(oscillator())
    sys = d.compile(1e-3)
    p = sys.params.copy()
    p[d.param_index("spring.stiffness_nm_per_rad")] = 16.0
    res = sys.simulate(2000, outputs=["angle_rad"], params=p)
    assert np.max(np.abs(res["angle_rad"] - np.cos(4.0 * res.t))) < 1e-8


def test_stepper_reproduces_simulate():
    d = Diagram(oscillator(b=0.3))
    sys = d.compile(1e-3)
    res = sys.simulate(500, outputs=["angle_rad"])
    st = sys.stepper(outputs=["angle_rad"])
    ys = np.array([st.step(np.zeros(0))[0] for _ in range(500)])
    np.testing.assert_allclose(ys, res["angle_rad"], rtol=0, atol=1e-15)


def test_damped_energy_decays_and_undamped_energy_is_kept():
    for b, decays in ((0.0, False), (1.0, True)):
        res = Diagram(oscillator(b=b)).compile(1e-3).simulate(4000, outputs=["angle_rad", "velocity_rad_s"])
        e = 0.5 * res["velocity_rad_s"] ** 2 + 0.5 * 4.0 * res["angle_rad"] ** 2
        if decays:
            assert e[-1] < 0.1 * e[0]
        else:
            assert abs(e[-1] - e[0]) < 1e-9 * max(1.0, e[0]) + 1e-10
    assert math.isclose(e[0], 2.0)
