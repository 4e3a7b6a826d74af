"""The workflow on real records no one here wrote (issue 38 item 6): a DC motor driving a generator
(Lacerda Junior et al. 2017; tests/data/dc_motor_generator/README.md). Its drive cannot brake (the
speed coasts down under a Coulomb-like deceleration with the command at 0, bench/real_data.py's
independent fit), which no library effect is: the verdict must say so with its figures, name
nothing, and never call the model a fit."""

from __future__ import annotations

from pathlib import Path

import pytest

from rehab_hil.discrepancy.workflow import Options, find_missing_effects
from rehab_hil.loading import load_config
from rehab_hil.plants import get_plant
from rehab_hil.rig_recording import load_recording

ROOT = Path(__file__).resolve().parents[2]
DATA = ROOT / "tests" / "data" / "dc_motor_generator" / "motor_generator_30s.csv"


@pytest.mark.slow
def test_a_drive_that_cannot_brake_is_an_unexplained_residual_with_its_figures_not_a_fit():
    cfg = load_config(ROOT / "configs" / "dc_motor_generator.toml")
    rec = load_recording(DATA, get_plant(cfg.plant), cfg).recording  # a logger CSV through [import]
    assert rec.t.size == 15000 and set(rec.signals) == {"drive_input_v", "velocity_rad_s"}
    res = find_missing_effects(cfg, rec, DATA, options=Options(max_effects=1))
    assert res.named == [] and res.parameters == []
    stats = res.residuals()["velocity_rad_s"]
    assert stats["share_of_spread"] > 0.3 and not stats["at_noise"]
    assert res.conclusion.startswith("unexplained residual on velocity_rad_s (")
    assert "% of its spread; noise floor" in res.conclusion and "fits" not in res.conclusion
