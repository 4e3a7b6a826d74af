"""The part/diagram framework: wiring, declared sums, ordering, errors, and the integrator's accuracy."""

from __future__ import annotations

import ast
import math
from pathlib import Path

import numpy as np
import pytest

from rehab_hil.models.mechanics import CoulombFriction, RotaryInertia, TorsionSpring, ViscousFriction
from rehab_hil.models.sensors import Gain
from rehab_hil.models.system import Diagram, DiagramError

OSC_SUMS = ("torque_nm",)  # the spring and the damper act on one mass


def oscillator(k=4.0, b=0.0, j=1.0, x0=(1.0, 0.0)):
    return [
        RotaryInertia("mass", connect={"torque_nm": "torque_nm"}, x0=list(x0), inertia_kg_m2=j),
        TorsionSpring("spring", rename={"torque_nm": "torque_nm"}, stiffness_nm_per_rad=k, rest_angle_rad=0.0),
        ViscousFriction("damper", rename={"torque_nm": "torque_nm"}, damping_nm_s_per_rad=b),
    ]


def test_rk4_matches_the_analytic_oscillator_to_fourth_order():
    sys = Diagram(oscillator(), inputs=(), sums=OSC_SUMS).compile(dt=1e-3)
    res = sys.simulate(5000, outputs=["angle_rad"])
    exact = np.cos(2.0 * res.t)
    assert np.max(np.abs(res["angle_rad"] - exact)) < 1e-9


def test_substeps_refine_a_coarse_step():
    d = Diagram(oscillator(), inputs=(), sums=OSC_SUMS)
    coarse = d.compile(dt=0.05).simulate(200, outputs=["angle_rad"])
    fine = d.compile(dt=0.05, substeps=8).simulate(200, outputs=["angle_rad"])
    exact = np.cos(2.0 * coarse.t)
    err_c = np.max(np.abs(coarse["angle_rad"] - exact))
    err_f = np.max(np.abs(fine["angle_rad"] - exact))
    assert err_f < err_c / 1000  # RK4: error ~ h^4, 8x smaller step -> ~4096x smaller error


def test_outputs_at_a_declared_sum_are_summed_and_unproduced_inputs_are_external():
    parts = [
        Gain("a", connect={"u": "x_in"}, rename={"y": "total"}, gain=2.0),
        Gain("b", connect={"u": "x_in"}, rename={"y": "total"}, gain=3.0),
        Gain("c", connect={"u": [("total", 1.0), ("other_in", -1.0)]}, rename={"y": "out"}, gain=1.0),
    ]
    d = Diagram(parts, inputs=("x_in", "other_in"), sums=("total",))
    assert set(d.input_names) == {"x_in", "other_in"}
    res = d.compile(0.01).simulate(3, inputs={"x_in": 1.0, "other_in": 0.5}, outputs=["total", "out"])
    assert np.allclose(res["total"], 5.0)
    assert np.allclose(res["out"], 4.5)


def test_two_parts_publishing_one_undeclared_signal_are_refused_naming_both():
    # un-renamed, both inertias publish angle_rad: summed, angle_rad would read 3.0 rad with each at 1.5
    parts = [RotaryInertia(name, x0=[1.5, 0.0], inertia_kg_m2=1.0) for name in ("a", "b")]
    with pytest.raises(DiagramError) as err:
        Diagram(parts, inputs=("torque_nm",))
    assert str(err.value) == (
        "signal 'angle_rad' is produced by parts 'a' and 'b'; only signals declared summable (sums=...) "
        "may have several producers"
    )


def test_the_refusal_names_every_producer_of_the_undeclared_signal():
    parts = [Gain(name, connect={"u": "x_in"}, rename={"y": "total"}, gain=1.0) for name in ("a", "b", "c")]
    with pytest.raises(DiagramError, match=r"signal 'total' is produced by parts 'a', 'b' and 'c';"):
        Diagram(parts, inputs=("x_in",), sums=("other",))


def test_a_declared_sum_that_no_part_produces_or_that_one_part_produces_is_allowed():
    parts = [Gain("a", connect={"u": "x_in"}, rename={"y": "total"}, gain=2.0)]
    d = Diagram(parts, inputs=("x_in",), sums=("total", "heat_flow_w"))
    assert "heat_flow_w" not in d.signal_names
    res = d.compile(0.01).simulate(2, inputs={"x_in": 1.0}, outputs=["total"])
    assert np.allclose(res["total"], 2.0)


def test_sums_given_as_one_string_are_refused():
    with pytest.raises(DiagramError, match="sums must be a sequence of signal names"):
        Diagram(oscillator(), inputs=(), sums="torque_nm")


def test_feedthrough_parts_are_evaluated_after_their_sources():
    # declared in reverse order: c reads b reads a
    parts = [
        Gain("c", connect={"u": "sb"}, rename={"y": "sc"}, gain=10.0),
        Gain("b", connect={"u": "sa"}, rename={"y": "sb"}, gain=10.0),
        Gain("a", connect={"u": "x_in"}, rename={"y": "sa"}, gain=10.0),
    ]
    res = Diagram(parts, inputs=("x_in",)).compile(0.01).simulate(2, inputs={"x_in": 1.0}, outputs=["sc"])
    assert np.allclose(res["sc"], 1000.0)


def test_algebraic_loop_is_refused_with_the_parts_named():
    parts = [Gain("a", connect={"u": "sb"}, rename={"y": "sa"}, gain=1.0),
             Gain("b", connect={"u": "sa"}, rename={"y": "sb"}, gain=1.0)]
    with pytest.raises(DiagramError, match="algebraic loop"):
        Diagram(parts, inputs=())


@pytest.mark.parametrize(
    ("make", "fragment"),
    [
        (lambda: Gain("g", gain=1.0, bogus=2.0), "unknown parameters"),
        (lambda: Gain("g"), "missing parameters"),
        (lambda: Gain("g", connect={"nope": "x"}, gain=1.0), "has no inputs"),
        (lambda: Gain("g", rename={"nope": "x"}, gain=1.0), "has no outputs"),
        (lambda: Diagram([Gain("g", gain=1.0), Gain("g", gain=2.0)], inputs=("u",)), "duplicate part names"),
    ],
)
def test_wiring_mistakes_are_refused(make, fragment):
    with pytest.raises(DiagramError, match=fragment):
        make()


def test_a_misspelled_signal_is_refused_with_the_closest_name():
    parts = [
        RotaryInertia("iris", connect={"torque_nm": "torque_nm"}, rename={"velocity_rad_s": "iris_velocity_rad_s"},
                      inertia_kg_m2=1.0),
        CoulombFriction("coulomb", connect={"velocity_rad_s": "iris_velocty_rad_s",
                                            "other_torque_nm": "patient_torque_nm"},
                        rename={"torque_nm": "torque_nm"}, level_nm=0.1, stick_velocity_rad_s=1e-3,
                        stick_damping_nm_s_per_rad=1.0),
    ]
    with pytest.raises(DiagramError) as err:
        Diagram(parts, inputs=("patient_torque_nm",))
    assert str(err.value) == (
        "part 'coulomb' input 'velocity_rad_s' reads 'iris_velocty_rad_s', which no part produces and is not "
        "a declared input; did you mean 'iris_velocity_rad_s'?"
    )


def test_a_declared_input_that_no_part_produces_is_external():
    parts = [Gain("g", connect={"u": "x_in"}, rename={"y": "out"}, gain=2.0)]
    d = Diagram(parts, inputs=("x_in", "unused_in"))
    assert d.input_names == ("x_in",)  # declared but unread: allowed, not an input
    res = d.compile(0.01).simulate(2, inputs={"x_in": 1.5}, outputs=["out"])
    assert np.allclose(res["out"], 3.0)


def test_a_declared_input_that_a_part_produces_is_not_external():
    # the bare plant takes "cmd" from outside; with a controller part in the diagram it is produced
    plant = Gain("plant", connect={"u": "cmd"}, rename={"y": "out"}, gain=2.0)
    controller = Gain("controller", connect={"u": "ref"}, rename={"y": "cmd"}, gain=3.0)
    assert Diagram([plant], inputs=("cmd", "ref")).input_names == ("cmd",)
    d = Diagram([plant, controller], inputs=("cmd", "ref"))
    assert d.input_names == ("ref",)
    res = d.compile(0.01).simulate(2, inputs={"ref": 1.0}, outputs=["out"])
    assert np.allclose(res["out"], 6.0)


def test_the_engine_builds_from_the_layout_alone():
    """No import cycle: engine.py imports nothing from system.py; the layout carries what it needs."""
    import rehab_hil.models.engine as engine

    tree = ast.parse(Path(engine.__file__).read_text())
    imported = {n.module for n in ast.walk(tree) if isinstance(n, ast.ImportFrom)}
    imported |= {a.name for n in ast.walk(tree) if isinstance(n, ast.Import) for a in n.names}
    assert "rehab_hil.models.system" not in imported
    d = Diagram(oscillator(), inputs=(), sums=OSC_SUMS)
    assert d.layout.input_names == d.input_names and d.layout.order == tuple(d.order)
    assert "rehab_hil.models.mechanics" in d.layout.kernel_modules


def test_params_vector_changes_behaviour_without_recompiling():
    d = Diagram(oscillator(), inputs=(), sums=OSC_SUMS)
    sys = d.compile(1e-3)
    p = sys.params.copy()
    p[d.param_index("spring.stiffness_nm_per_rad")] = 16.0
    res = sys.simulate(2000, outputs=["angle_rad"], params=p)
    assert np.max(np.abs(res["angle_rad"] - np.cos(4.0 * res.t))) < 1e-8


def test_stepper_reproduces_simulate():
    d = Diagram(oscillator(b=0.3), inputs=(), sums=OSC_SUMS)
    sys = d.compile(1e-3)
    res = sys.simulate(500, outputs=["angle_rad"])
    st = sys.stepper(outputs=["angle_rad"])
    ys = np.array([st.step(np.zeros(0))[0] for _ in range(500)])
    np.testing.assert_allclose(ys, res["angle_rad"], rtol=0, atol=1e-15)


def test_damped_energy_decays_and_undamped_energy_is_kept():
    for b, decays in ((0.0, False), (1.0, True)):
        sys = Diagram(oscillator(b=b), inputs=(), sums=OSC_SUMS).compile(1e-3)
        res = sys.simulate(4000, outputs=["angle_rad", "velocity_rad_s"])
        e = 0.5 * res["velocity_rad_s"] ** 2 + 0.5 * 4.0 * res["angle_rad"] ** 2
        if decays:
            assert e[-1] < 0.1 * e[0]
        else:
            assert abs(e[-1] - e[0]) < 1e-9 * max(1.0, e[0]) + 1e-10
    assert math.isclose(e[0], 2.0)
