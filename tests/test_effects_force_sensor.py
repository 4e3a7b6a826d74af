"""The force-sensor creep and hysteresis effect (effects.py ``sensor_creep_hysteresis``,
models/effect_parts.SensorCreepHysteresis), identified on FlexiForce staircases
(analysis/flexiforce.py): its response to a load staircase, its inverse on a recorded input,
chaining with the gain/offset effect, and the workflow naming it on a force trace with creep."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from rehab_hil.discrepancy.synthetic import hidden_effect_recording
from rehab_hil.discrepancy.workflow import Options, find_missing_effects
from rehab_hil.effects import attach
from rehab_hil.loading import load_config
from rehab_hil.models.effect_parts import SensorCreepHysteresis
from rehab_hil.models.system import Diagram
from rehab_hil.plants import get_plant

CONFIGS = Path(__file__).resolve().parents[1] / "configs"


def _staircase(invert: float, u: np.ndarray, c=0.1, tau=2.0, width=20.0) -> np.ndarray:
    part = SensorCreepHysteresis("s", connect={"u": "true_n"}, rename={"y": "read_n"}, creep_fraction=c,
                                 creep_time_s=tau, hysteresis_counts=width, counts_per_unit=100.0, invert=invert)
    system = Diagram([part], inputs=("true_n",)).compile(0.01, 1)
    return system.simulate(u.size, {"true_n": u}, outputs=["read_n"])["read_n"]


def test_a_load_step_creeps_by_the_fraction_with_the_time_constant_and_unloading_reads_high() -> None:
    load = np.concatenate([np.zeros(10), np.full(2000, 5.0), np.full(2000, 2.0)])
    y = _staircase(0.0, load)
    assert y[11] == pytest.approx(5.0 - 0.1, abs=0.02)  # loading: half the 0.2 N play below, no creep yet
    assert y[10 + 200] - y[11] == pytest.approx(0.1 * 5.0 * (1 - np.exp(-1.0)), rel=0.05)  # one tau later
    assert y[2009] == pytest.approx(5.0 * 1.1 - 0.1, abs=0.01)
    assert y[-1] == pytest.approx(2.0 * 1.1 + 0.1, abs=0.01)  # unloading: half the play above


def test_on_a_recorded_input_the_inverse_removes_the_creep() -> None:
    true = np.concatenate([np.zeros(10), np.full(1000, 3.0), np.full(1000, 1.0)])
    measured = _staircase(0.0, true, width=0.0)
    assert np.allclose(_staircase(1.0, measured, width=0.0), true, atol=1e-3)  # 1 mN of 3 N: the ZOH


def test_it_chains_with_the_gain_offset_effect_on_one_modelled_force() -> None:
    spec, cfg = get_plant("tcp_finger"), load_config(CONFIGS / "tcp_finger.toml")
    parts = attach(spec.name, spec.ports(cfg), 0.001, spec.build(cfg),
                   [("sensor_gain_offset", {"gain_error_fraction": 0.1}), ("sensor_creep_hysteresis", {})])
    producers = {s: p.name for p in parts for s in p.signal_names}
    assert producers["tcp_force_n"] == "effect_sensor_creep_hysteresis"
    assert producers["tcp_force_n_true2"] == "effect_sensor_gain_offset"
    Diagram(parts, inputs=spec.external_inputs(cfg), sums=spec.ports(cfg).sums)  # one producer per signal


def test_the_workflow_names_sensor_creep_on_a_force_trace_with_creep() -> None:
    spec, cfg = get_plant("tcp_finger"), load_config(CONFIGS / "tcp_finger.toml")
    hidden = {"creep_fraction": 0.1, "creep_time_s": 4.0, "hysteresis_counts": 20.0}
    rec = hidden_effect_recording(spec, cfg, {"sensor_creep_hysteresis": hidden}, duration_s=15.0, seed=1)
    res = find_missing_effects(cfg, rec, "creep.csv", options=Options(max_effects=1, joint=False))
    assert res.named == ["sensor_creep_hysteresis"], res.conclusion
    fit = res.chosen[0].params
    assert fit["creep_fraction"] == pytest.approx(0.1, rel=0.2)
    assert fit["creep_time_s"] == pytest.approx(4.0, rel=0.25)
