"""The patient's torque estimated by the twin from the host's model and the rig's angle and force
sensors (``twin/patient_torque.py``): a known torque on the plant is found without its sensor; in
assist-as-needed sessions with a simulated patient the per-move estimate in ``session_cycles`` is scored
against ``sim_truth.csv`` (which the estimate never reads)."""

from __future__ import annotations

import dataclasses
import json
import math
from pathlib import Path
from types import SimpleNamespace
from typing import Any

import numpy as np
import pytest

from rehab_hil.controllers import Reference
from rehab_hil.devices.plant_io import PlantIO
from rehab_hil.loading import load_config
from rehab_hil.loop.controllers import Command
from rehab_hil.loop.estimation import Estimator
from rehab_hil.loop.records import SampleRecord
from rehab_hil.patient.truth import TRUTH_FILE, read_truth
from rehab_hil.plants.registry import get_plant
from rehab_hil.protocol import DUTY_FULL
from rehab_hil.service.session import open_session
from rehab_hil.therapy_measures import move_windows
from rehab_hil.twin.live import Twin

ROOT = Path(__file__).resolve().parents[2]
FE = ROOT / "configs" / "finger_extensor.toml"
SMA = ROOT / "configs" / "sma_exoskeleton.toml"
TCP = ROOT / "configs" / "tcp_finger.toml"


def _session(config: Path, patient: str, cycles: int, out: Path) -> dict[str, Any]:
    """An assist-as-needed session on the in-process rig with the twin; its cycles, truth and reference."""
    ref = Reference.session(load_config(config))
    with open_session(config, "inprocess", controller="assist_as_needed", twin=True, record=out,
                      sim_patient=ROOT / "profiles" / "sim" / f"{patient}.toml", learning_store=out / "store") as s:
        res = s.run(ref.first_open_s + cycles * ref.period_s + 0.5)
        run_dir = s.run_dir
    meta = json.loads((run_dir / "metadata.json").read_text())
    return {"events": res.events, "cycles": meta["session_cycles"], "meta": meta, "ref": ref,
            "truth": read_truth(run_dir / TRUTH_FILE)}


@pytest.fixture(scope="module")
def sessions(tmp_path_factory) -> dict[str, dict[str, Any]]:
    """Each session once for the module (in-process, lockstep: seconds each)."""
    cache: dict[str, dict[str, Any]] = {}

    def get(config: Path, patient: str, cycles: int) -> dict[str, Any]:
        key = f"{config.stem}-{patient}-{cycles}"
        if key not in cache:
            cache[key] = _session(config, patient, cycles, tmp_path_factory.mktemp(key))
        return cache[key]
    return get  # type: ignore[return-value]


def _per_move(run: dict[str, Any], key: str) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(estimate, its half-interval, truth) of each cycle's opening (``key`` "open") or closing move,
    toward the move's target [N m]; the truth as the host's windows see it."""
    ref, truth = run["ref"], run["truth"]
    sign = 1.0 if ref.open_deg >= ref.closed_deg else -1.0
    window = move_windows(ref.period_s, ref.move_s)[0 if key == "open" else 1]
    if key == "close":
        sign = -sign
    t, tau = truth["t_s"], truth["patient_axis_torque_nm"]
    true = [sign * np.mean(tau[(t >= c["start_s"] + window[0]) & (t <= c["start_s"] + window[1])])
            for c in run["cycles"]]
    est = [c[f"patient_torque_{key}_model_nm"] for c in run["cycles"]]
    ci = [c[f"patient_torque_{key}_model_ci_nm"] for c in run["cycles"]]
    return np.array(est), np.array(ci), np.array(true)


def test_a_known_torque_on_the_finger_extensor_is_found_from_the_encoder_without_the_torque_sensor():
    cfg = load_config(FE)
    binding = get_plant(cfg.plant).device(cfg)
    period = 1.0 / cfg.rig.sample_rate_hz
    torque_nm = 0.12  # on the iris axis: the plant's patient input is its negative (the sensor's sign)
    io = PlantIO(dataclasses.replace(binding, constant_inputs={**binding.constant_inputs,
                                                                "patient_torque_nm": -torque_nm}))
    host = Estimator(binding, 30.0)
    twin_in = Twin(cfg, binding, period, check_speed=False)  # the twin's own path from a sample to the model
    n = 6000
    duty = 0.35 * np.sin(2 * np.pi * np.arange(n) * period / 3.0)  # the iris moves both ways
    for k, d in enumerate(duty):
        counts, direction = round(abs(float(d)) * DUTY_FULL), int(d < 0)
        enc, a0, a1 = io.tick((counts, 0), direction)
        state = host.update(enc, int(k * period * 1e6), (a0, a1))
        smp = SimpleNamespace(duty0=counts, duty1=0, direction=direction)
        twin_in.feed(SampleRecord(0.0, k * period, smp, state, Command(), k, math.nan))
    twin_in.finish()
    est = twin_in.patient_torque
    assert est is not None and est.source == "model + encoder"
    segs = est.segments
    assert len(segs) > 15
    late = [s.torque_nm for s in segs if s.t0_s >= 1.0]  # after the first second (the start speed is unknown)
    assert np.median(late) == pytest.approx(torque_nm, rel=0.1)
    mean, ci = est.window(1.0, n * period, 1.0)
    assert abs(mean - torque_nm) <= max(ci, 0.1 * torque_nm) and 0 < ci < torque_nm
    # the torque sensor read the torque all along (the twin's own model takes it as its input): had the
    # estimate used it, its load would have found nothing left to explain
    assert twin_in.model.adc_inputs == ["patient_torque_nm"]


def test_the_capable_patients_torque_on_the_finger_extensor_is_estimated_within_15_percent_per_direction(sessions):
    run = sessions(FE, "capable", 3)
    assert run["events"] == []
    for key in ("open", "close"):
        est, ci, true = _per_move(run, key)
        assert np.all(np.isfinite(est)) and np.all(ci > 0)
        assert abs(est.mean() - true.mean()) <= 0.15 * abs(true.mean())  # the target, per direction
        assert np.max(np.abs(est - true)) <= 0.15 * np.max(np.abs(true))  # and every move within 15 % of the largest
    c = run["cycles"][0]
    assert c["patient_torque_source"] == "torque sensor" and c["patient_torque_model_source"] == "model + encoder"
    assert math.isfinite(c["patient_torque_open_nm"])  # the sensor's figure stays beside the model's
    assert run["meta"]["twin"]["patient_torque"]["segments"] > 100
    assert math.isfinite(run["meta"]["session"]["patient_torque_open_model_nm"])


def test_with_the_passive_patient_the_estimate_is_the_passive_fingers_torque_and_no_voluntary_one(sessions):
    passive, capable = sessions(FE, "passive", 3), sessions(FE, "capable", 3)
    assert not np.any(passive["truth"]["patient_voluntary_nm"])
    for key in ("open", "close"):
        est, ci, true = _per_move(passive, key)
        strong = np.max(np.abs(_per_move(capable, key)[2]))
        # within 0.02 N m of the passive finger's torque in every move: a tenth of what the capable patient makes
        assert np.max(np.abs(est - true)) <= 0.1 * strong
        assert np.mean(np.abs(est - true) <= ci + 0.005) >= 0.5  # the interval holds it (to 5 mN m) in most moves


def test_on_the_sma_exoskeleton_the_estimate_from_the_encoder_and_flexiforce_has_the_truths_sign_and_size(sessions):
    run = sessions(SMA, "weak", 3)
    assert run["events"] == []
    assert run["cycles"][0]["patient_torque_model_source"] == "model + encoder + contact_force_n"
    assert "patient_torque_source" not in run["cycles"][0]  # no torque sensor on this rig
    for key in ("open", "close"):
        est, ci, true = _per_move(run, key)
        assert np.all(np.isfinite(est)) and np.all(np.isfinite(ci)) and np.all(ci > 0)
        big = np.abs(true) > 0.03
        assert np.all(np.sign(est[big]) == np.sign(true[big]))
        # 0.03 N m in each move, a quarter of the largest true torque: the model's pad and wire beside a
        # finger whose passive torque the model does not have (docs/patient.md)
        assert np.max(np.abs(est - true)) <= 0.03
        assert abs(est.mean() - true.mean()) <= 0.2 * abs(true.mean())


@pytest.mark.slow
def test_on_the_tcp_finger_the_weak_patients_torque_is_found_from_the_encoder_and_the_tendon_force(sessions):
    run = sessions(TCP, "weak", 1)  # one 60 s cycle
    assert run["cycles"][0]["patient_torque_model_source"] == "model + tcp_force_n + encoder"
    for key in ("open", "close"):
        est, ci, true = _per_move(run, key)
        assert np.all(np.isfinite(ci)) and np.all(ci > 0)
        assert np.all(np.sign(est) == np.sign(true))
        # the host's model is the simulated finger's, the patient apart: what is left is the windows' edges
        assert np.max(np.abs(est - true)) <= 0.05 * np.max(np.abs(true))
