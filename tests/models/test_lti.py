"""SISO state-space parts: every seed 001 Table 1 transfer function, realised as a part, has
python-control's step response; operating points shift input and output."""

from __future__ import annotations

from pathlib import Path

import control
import numpy as np
import pytest

from rehab_hil.loading import load_config
from rehab_hil.models.lti import StateSpace1, lti_part, peak_after_cut_part, state_space_params
from rehab_hil.models.system import Diagram, DiagramError
from rehab_hil.plants.tcp_finger import table1

DT = 1e-3
N = 20_000


CFG = Path(__file__).resolve().parents[2] / "configs" / "tcp_finger.toml"


@pytest.fixture(scope="module")
def tfs():
    return table1(load_config(CFG))


@pytest.fixture(scope="module")
def bank(tfs):
    """One compiled diagram with one part of each order 1..3 in parallel on input ``u``."""
    parts = [lti_part(f"ss{n}", tf, connect={"u": "u"}, rename={"y": f"y{n}"})
             for n, tf in ((1, tfs["TP01"]), (2, tfs["TP002"]), (3, tfs["TP03"]))]
    diagram = Diagram(parts, inputs=("u",))
    return diagram, diagram.compile(DT, 1)


def test_table1_has_seven_models_each_way(tfs):
    assert sorted(k for k in tfs if k.startswith("TP")) == ["TP002", "TP01", "TP02", "TP03", "TP1", "TP2", "TP3"]
    assert sorted(k for k in tfs if k.startswith("FT")) == ["FT002", "FT01", "FT02", "FT03", "FT1", "FT2", "FT3"]


@pytest.mark.parametrize("name", ["TP01", "TP1", "TP02", "TP002", "TP2", "TP03", "TP3",
                                  "FT01", "FT1", "FT02", "FT002", "FT2", "FT03", "FT3"])
def test_each_table1_part_has_the_step_response_of_python_control(bank, tfs, name):
    diagram, system = bank
    tf = tfs[name]
    n = len(tf.poles())
    p = system.params.copy()
    for key, value in state_space_params(tf).items():
        p[diagram.param_index(f"ss{n}.{key}")] = value
    res = system.simulate(N, {"u": 1.0}, outputs=[f"y{n}"], params=p)
    ref = control.step_response(tf, T=res.t).outputs
    y = res[f"y{n}"]
    scale = np.max(np.abs(ref))
    assert scale > 0
    np.testing.assert_allclose(y, ref, rtol=0, atol=1e-6 * scale)


def test_operating_point_shifts_input_and_output(bank, tfs):
    diagram, system = bank
    p = system.params.copy()
    for key, value in state_space_params(tfs["TP01"], u0=2.0, y0=25.0).items():
        p[diagram.param_index(f"ss1.{key}")] = value
    res = system.simulate(2000, {"u": 2.0}, outputs=["y1"], params=p)
    np.testing.assert_allclose(res["y1"], 25.0, atol=1e-12)  # at the operating point nothing moves


def test_orders_above_three_are_refused():
    with pytest.raises(ValueError, match="order 4"):
        state_space_params(control.tf([1.0], [1.0, 4.0, 6.0, 4.0, 1.0]))


def test_a_part_needs_every_matrix_entry():
    with pytest.raises(DiagramError, match="missing parameters"):
        StateSpace1("x", a11=-1.0, b1=1.0, c1=1.0, d=0.0, u0=0.0)


@pytest.mark.parametrize("name", ["TP002", "TP02", "TP01"])
def test_the_peak_after_a_cut_bounds_what_the_output_still_rises_to(tfs, name):
    """Power held 20 s, then cut: python-control's response after the cut never passes the bound the
    part gives at the cut. A second-order lag (TF_TP02) goes on rising after the cut; TF_TP002's fast
    mode hides heat while the power is on (its residue, the
    rig's thermal estimate's second mode: -159.9 C at 60 W, -2.665 C/W) and gives it back within a
    second: the temperature rises after the cut, and the bound is the output plus that hidden heat."""
    tf = tfs[name]
    part = lti_part("tf", tf, connect={"u": "u"})
    peak = peak_after_cut_part("peak", part, connect={"u": "u"})
    system = Diagram([part, peak], inputs=("u",)).compile(DT, 1)
    hold = 20_000
    res = system.simulate(hold + 1, {"u": 1.0}, outputs=["y", "peak"])
    at_cut, bound = res["y"][-1], res["peak"][-1]
    t = np.arange(0.0, 60.0, DT)
    after = np.asarray(control.forced_response(tf, T=t, U=np.where(t < hold * DT, 1.0, 0.0)).outputs)[hold:]
    assert after.max() <= bound + 1e-6 * abs(bound)
    if name == "TP01":  # one mode: the output is its own bound
        assert bound == pytest.approx(at_cut, rel=1e-9)
        return
    assert after.max() > at_cut  # a rise a ceiling on the output itself misses
    if name == "TP002":
        assert after.max() > at_cut + 0.3
        assert bound - at_cut == pytest.approx(159.9 / 60.0, rel=2e-3)


def test_no_peak_bound_where_the_output_reads_its_input_or_its_modes_oscillate(tfs):
    assert peak_after_cut_part("p", lti_part("tf", tfs["TP1"], connect={"u": "u"})) is None  # biproper
    assert peak_after_cut_part("p", lti_part("tf", tfs["TP03"], connect={"u": "u"})) is None  # -3.24 +- 0.34j
