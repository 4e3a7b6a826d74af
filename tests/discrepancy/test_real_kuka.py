"""The workflow on real records no one here wrote, turning both ways (issue 38 item 6): axis 1 of a
KUKA KR300 industrial robot (Weigand et al. 2021; tests/data/kuka_kr300_axis1/README.md), two 10 s
records fitted together as the CLI does with several ``--data``. From the model without Coulomb
friction the workflow names Coulomb friction at the level an independent least-squares fit of the
same records finds (within 30 %), and nothing else, and record C held out agrees; from the reference
model holding the published friction it names no library effect. The records show no direction
asymmetry the search can demonstrate (the independent fit: 8 % between the directions over both
records, 28 % on one and none on the other), and none is named.

Held-out data judge the findings (issue 47 item 4): from the reference model (Coulomb friction and
its asymmetry, 409.5 N m against turning +, 301.5 N m against turning -), record C alone names a
constant load of -65.5 N m (C's own held-out part agrees: on C the asymmetry is not there) that
makes records A and B worse than the model as given (A's angle RMSE 5.72 -> 13.3 deg); with A and B
as validation records it is rejected, not reported, and the given value kept."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from scipy.signal import savgol_filter

from rehab_hil.discrepancy.validation import validate
from rehab_hil.discrepancy.workflow import Options, find_missing_effects
from rehab_hil.loading import load_config
from rehab_hil.plants import get_plant
from rehab_hil.rig_recording import load_recording

ROOT = Path(__file__).resolve().parents[2]
DATA = ROOT / "tests" / "data" / "kuka_kr300_axis1"
RECORDS = [DATA / "record_a.csv", DATA / "record_b.csv"]
GEAR = 256.8571  # u(1) of the records' para struct: motor torque x u = link torque
CLI = Options(max_effects=3, search="sets", start="auto")  # what `rehab-hil discrepancy --data A --data B` runs
CLI_ONE = Options(max_effects=2, start="auto")  # and `--data C` alone (the rounds)


def independent_coulomb() -> tuple[float, float, float]:
    """Least squares of the link torque, tau = J q'' + Fv q' + Fc sgn(q') (+ a level per direction),
    over both records' samples turning faster than 0.01 rad/s: (Fc, Fc turning +, Fc turning -)."""
    rows = [np.genfromtxt(p, delimiter=",", names=True) for p in RECORDS]
    q = [np.radians(r["act_pos_mot_deg_1"]) for r in rows]
    v = np.concatenate([savgol_filter(x, 11, 3, deriv=1, delta=0.004) for x in q])
    a = np.concatenate([savgol_filter(x, 11, 3, deriv=2, delta=0.004) for x in q])
    tau = np.concatenate([r["act_torque_abs_nm_1"] for r in rows]) * GEAR
    m = np.abs(v) > 0.01
    sym, *_ = np.linalg.lstsq(np.column_stack([a, v, np.sign(v)])[m], tau[m], rcond=None)
    per, *_ = np.linalg.lstsq(np.column_stack([a, v, v > 0, -1.0 * (v < 0)]).astype(float)[m], tau[m], rcond=None)
    return float(sym[2]), float(per[2]), float(per[3])


def _load(config: str, paths: list[Path]):
    cfg = load_config(ROOT / "configs" / config)
    recs = [load_recording(p, get_plant(cfg.plant), cfg).recording for p in paths]  # through [import]
    assert all(set(r.signals) == {"drive_torque_nm", "angle_deg", "velocity_rad_s"} for r in recs)
    return cfg, recs


def _run(config: str, validate_on: list[Path] = ()):
    cfg, recs = _load(config, RECORDS)
    held = list(zip(_load(config, list(validate_on))[1], validate_on, strict=True))
    return find_missing_effects(cfg, recs, RECORDS, options=CLI, validation=held)


@pytest.mark.slow
def test_from_the_model_without_coulomb_friction_coulomb_friction_is_named_at_the_independent_fits_level():
    fc, pos, neg = independent_coulomb()
    assert 300.0 < fc < 420.0 and abs(pos / neg - 1.0) < 0.15  # the records: about 350 N m, both ways alike
    res = _run("kuka_kr300_axis1_nominal.toml", [DATA / "record_c.csv"])  # as `--validate record_c.csv`
    assert res.named == ["coulomb_friction"] and res.parameters == []  # no spurious term
    level = res.chosen[0].params["level_nm"]
    assert level == pytest.approx(fc, rel=0.30)
    for g in res.gaps["records"]:  # the whole-record replay of each record: the angle error falls by more than half
        assert g["augmented"]["angle_deg"]["rmse"] < 0.5 * g["nominal"]["angle_deg"]["rmse"]
    judged = res.judgement  # the held-out record agrees: nothing rejected, its angle error falls by more than half
    assert judged.where == "the validation records" and res.rejected == []
    assert judged.final.rmse["angle_deg"] < 0.5 * judged.given.rmse["angle_deg"]


@pytest.mark.slow
def test_from_the_reference_model_no_library_effect_is_named():
    res = _run("kuka_kr300_axis1.toml")
    assert res.named == []
    assert res.conclusion.startswith("unexplained residual on")  # the arm's changing inertia: said, not fitted away


@pytest.mark.slow
def test_a_finding_the_held_out_records_make_worse_is_rejected_and_the_given_friction_kept():
    cfg, (c,) = _load("kuka_kr300_axis1.toml", [DATA / "record_c.csv"])
    _, others = _load("kuka_kr300_axis1.toml", RECORDS)
    held = list(zip(others, RECORDS, strict=True))  # A and B, as `--validate record_a.csv --validate record_b.csv`
    res = find_missing_effects(cfg, c, DATA / "record_c.csv", options=CLI_ONE, validation=held)
    assert res.named == [] and res.parameters == []
    (r,) = res.rejected
    assert r.terms == ("constant_load",) and r.findings[0].startswith("constant_load (level -")
    assert r.with_terms.rmse["angle_deg"] > r.without.rmse["angle_deg"]
    assert "the validation records rejected constant_load" in res.conclusion and "it is not added" in res.conclusion
    for rec, path in held:  # every validation record: no channel worse than with the model as given
        v = validate(res, cfg, rec, path)
        assert all(v.augmented[ch]["rmse"] <= v.nominal[ch]["rmse"] * (1 + 1e-9) for ch in v.channels)
    # judged on C's own held-out part instead, the same constant load stands: there the records agree with it
    alone = find_missing_effects(cfg, c, DATA / "record_c.csv", options=CLI_ONE)
    assert alone.named == ["constant_load"] and alone.rejected == []
    assert alone.judgement.where == "the records' held-out parts"
