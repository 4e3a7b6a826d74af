"""The twin's model follows the plant it models: driven by the duties the device reports applied,
re-anchored every segment, it predicts every measured channel to about a sensor count, with and
without samples lost on the way; a channel the rig does not measure is refused."""

from __future__ import annotations

import numpy as np
import pytest

from rehab_hil.config import TwinSection
from rehab_hil.loading import load_config
from rehab_hil.plants.registry import get_plant
from rehab_hil.twin.live import Twin
from rehab_hil.twin.model import TwinModel, TwinSetupError

from .conftest import CONFIGS, plant_records

N = 4000


def _residual_counts(config, duty, keep=None) -> np.ndarray:
    cfg, binding, records = plant_records(config, duty, keep=keep)
    twin = Twin(cfg, binding, 1.0 / cfg.rig.sample_rate_hz, TwinSection(diagnose=False), check_speed=False)
    rows: list[list[float]] = []

    class Keep:
        def prediction(self, msg: dict[str, float]) -> None:
            rows.append([msg[f"{c}_residual"] for c in twin.channels])

        def mismatch(self, event, final: bool) -> None:
            raise AssertionError(f"a model mismatch on its own plant: {event.text()}")

    twin.listeners.append(Keep())
    for r in records:
        twin.feed(r)
    twin.finish()
    return np.abs(np.array(rows)) / twin.model.resolution


def _levels(signed: bool, seed: int = 1) -> np.ndarray:
    rng = np.random.default_rng(seed)
    lv = np.repeat(rng.uniform(-1.0 if signed else 0.0, 1.0, N // 200), 200)
    return 0.6 * lv if signed else lv


@pytest.mark.parametrize("plant,signed", [("finger_extensor", True), ("tcp_finger", False),
                                          ("sma_exoskeleton", False)])
def test_the_twin_predicts_its_own_plant_to_about_a_count(plant: str, signed: bool) -> None:
    r = _residual_counts(CONFIGS / f"{plant}.toml", _levels(signed))
    assert np.sqrt(np.mean(r**2, axis=0)).max() < 1.5
    assert r.max() < 3.0


def test_lost_samples_hold_the_last_input_and_the_prediction_stays_close() -> None:
    keep = np.random.default_rng(2).random(N) > 0.1  # one sample in ten never reaches the twin
    r = _residual_counts(CONFIGS / "finger_extensor.toml", _levels(True), keep)
    assert np.sqrt(np.mean(r**2)) < 1.5
    assert r.max() < 5.0


def test_a_model_that_is_wrong_leaves_residuals_many_counts_large() -> None:
    """The same records against a model whose motor is 30 % weaker: the residual test has something to see."""
    cfg, binding, records = plant_records(CONFIGS / "finger_extensor.toml", _levels(True))
    weak = TwinModel(cfg, binding, 1.0 / cfg.rig.sample_rate_hz, 0.25)
    weak.P[weak.system.diagram.param_index("motor.kt_nm_per_a")] *= 0.7
    index = np.array([round(r.time_s * 1000) for r in records])
    U = np.array([weak.inputs_of(r.sample.duty0, 0, r.sample.direction, {}) for r in records])
    Y = np.array([[r.state.angle_deg + weak.encoder_centre_deg] for r in records])
    r = np.abs(weak.advance(index, U, Y).residual) / weak.resolution
    assert np.sqrt(np.mean(r**2)) > 5.0


def test_a_residual_on_a_channel_the_rig_does_not_measure_is_refused_naming_it() -> None:
    cfg = load_config(CONFIGS / "sma_exoskeleton.toml")
    binding = get_plant(cfg.plant).device(cfg)
    with pytest.raises(TwinSetupError, match="'theta_pip_deg': the rig does not measure it"):
        TwinModel(cfg, binding, 0.001, channels=["theta_pip_deg"])


def test_a_model_too_slow_for_the_loop_is_refused_in_one_line() -> None:
    cfg = load_config(CONFIGS / "tcp_finger.toml")
    binding = get_plant(cfg.plant).device(cfg)
    with pytest.raises(TwinSetupError) as e:
        Twin(cfg, binding, 0.001, TwinSection(min_realtime_factor=1e9))
    assert "cannot keep up with the loop" in str(e.value) and "\n" not in str(e.value)


def test_a_lockstep_sessions_twin_is_not_refused_for_its_speed_the_loop_waits_for_it() -> None:
    from rehab_hil.twin.session import start_twin

    cfg = load_config(CONFIGS / "tcp_finger.toml")
    cfg = cfg.model_copy(update={"twin": TwinSection(min_realtime_factor=1e9)})
    binding = get_plant(cfg.plant).device(cfg)
    with pytest.raises(TwinSetupError, match="cannot keep up"):
        start_twin(cfg, binding, 0.001, lockstep=False)
    run = start_twin(cfg, binding, 0.001, lockstep=True)
    assert run.live.close() is None and run.twin.samples == 0


def test_a_smooth_model_reads_the_encoder_angle_before_its_quantisation() -> None:
    """The estimate's model (``smooth``) predicts the angle the encoder measures, not its whole counts:
    a parameter change worth a fraction of a count moves it, where the counts stand still."""
    cfg = load_config(CONFIGS / "finger_extensor.toml")
    binding = get_plant(cfg.plant).device(cfg)
    count_deg = 360.0 / binding.encoder_counts_per_rev
    u = TwinModel(cfg, binding, 0.001).inputs_of(300, 0, 0, {})
    U = np.repeat(u[None, :], 200, axis=0)
    out = {}
    for smooth in (False, True):
        m = TwinModel(cfg, binding, 0.001, smooth=smooth)
        runs = []
        for scale in (1.0, 1.001):
            P = m.P.copy()
            P[m.system.diagram.param_index("iris.inertia_kg_m2")] *= scale
            runs.append(m.run(U, m.system.x0.copy(), m.system.xd0.copy(), P)[:, 0])
        out[smooth] = runs
    counts = out[False][0] / count_deg
    assert np.allclose(counts, np.round(counts)) and np.ptp(counts) > 10  # it moved, in whole counts
    assert np.array_equal(out[False][0], out[False][1])  # a 0.1 % change shows in no count
    assert 0.0 < np.max(np.abs(out[True][1] - out[True][0])) < count_deg  # ... but moves the smooth angle
    assert np.max(np.abs(out[True][0] - out[False][0])) <= 0.5 * count_deg + 1e-9  # the same angle, unrounded


def test_a_segment_whose_last_readings_are_all_lost_is_not_corrected_and_raises_no_warning() -> None:
    """The readings that end a segment, where the twin takes the error it anchors on, never came
    (the samples were lost, the channel stopped): no correction, a finite prediction, no RuntimeWarning."""
    import warnings

    cfg, binding, records = plant_records(CONFIGS / "finger_extensor.toml", _levels(True))
    twin = TwinModel(cfg, binding, 1.0 / cfg.rig.sample_rate_hz, 0.25)
    index = np.array([round(r.time_s * 1000) for r in records])
    U = np.array([twin.inputs_of(r.sample.duty0, 0, r.sample.direction, {}) for r in records])
    Y = np.array([[r.state.angle_deg + twin.encoder_centre_deg] for r in records])
    Y[: twin.segment_samples] = np.nan  # the whole first segment unread
    with warnings.catch_warnings():
        warnings.simplefilter("error", RuntimeWarning)
        block = twin.advance(index[: twin.segment_samples], U[: twin.segment_samples], Y[: twin.segment_samples])
    assert block.anchored[-1] and np.all(twin.last_correction == 0.0)
    assert np.all(np.isfinite(block.predicted)) and np.all(np.isfinite(twin.x))
