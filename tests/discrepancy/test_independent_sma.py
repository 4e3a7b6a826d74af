"""Issue 14 items 4-6 on SMA-exoskeleton records from the independent simulator
(bench/sma_independent.py): sessions cut mid-way, random duty trains, sensors only (a 4096-count
encoder and the Flexiforce through a 10-bit ADC). Pairs of hidden effects are both named."""

from __future__ import annotations

import numpy as np
import pytest

from rehab_hil.discrepancy.replay import Replay
from rehab_hil.discrepancy.workflow import Options, find_missing_effects
from rehab_hil.loading import load_config
from rehab_hil.plants import get_plant

from .conftest import ROOT

SMA_CONFIG = ROOT / "configs" / "sma_exoskeleton.toml"
MUSCLE = {"scale_nm": 0.01, "shape_per_rad": 2.0, "damping_nm_s_per_rad": 0.0}


@pytest.fixture(scope="module")
def cfg():
    return load_config(SMA_CONFIG)


# the two tests that read it run on one xdist worker, so the record is made once (on two workers, each
# made its own: 12.5 and 12.8 s of set-up under load)
CLEAN_624 = pytest.mark.xdist_group("independent_sma_clean_624")


@pytest.fixture(scope="module")
def clean_record(independent_sma):
    """The clean session cut (seed 624) the two replay checks read; neither changes it (a record from
    the independent simulator costs seconds)."""
    return independent_sma.sma_independent_record({}, {}, 624, 20.0, 500.0)


@CLEAN_624
def test_a_fit_sees_the_force_adc_floor_but_not_its_rounding(cfg, clean_record):
    """The model's contact force goes below zero while the passive wire holds a bend; the Flexiforce's
    ADC shows 0 there. A fit compares the model through the same floor (else a model force of -0.3 N
    against a logged 0 is an error a sensor gain would 'fit'), without rounding to counts (a rounded
    output is flat between counts and gives the fit no slope)."""
    replay = Replay.build(get_plant("sma_exoskeleton"), cfg, clean_record)
    offset, per_n, _ = replay.adc_range["contact_force_n"]
    P = replay.nominal_params()
    raw = replay.simulate_grid(P, replay.n_steps)[:, replay.channels.index("contact_force_n")]
    assert raw.min() < -0.05  # the model does go below the sensor's floor on this record
    fit_view = replay.simulate(P, sensed=False)["contact_force_n"]
    counts = offset + per_n * fit_view
    assert counts.min() >= -1e-9
    assert np.any(np.abs(counts - np.round(counts)) > 0.05)  # continuous above the floor
    sensed = offset + per_n * replay.simulate(P)["contact_force_n"]
    assert np.allclose(sensed, np.round(sensed))


@CLEAN_624
def test_a_channel_mostly_noise_weighs_less_in_the_fits(cfg, clean_record):
    """The encoder angle (0.09 deg counts over a 16 deg spread) and a force of a few ADC counts whose
    noise floor is a third of its scale: by spread alone the force's count scatter would weigh as
    much as the angle; its residual is divided by ten noise floors instead (``NOISY_SPREAD``), the
    angle's by its spread, in the fits and in the BIC."""
    from rehab_hil.discrepancy.replay import NOISY_SPREAD
    from rehab_hil.discrepancy.verdict import noise_floor

    replay = Replay.build(get_plant("sma_exoskeleton"), cfg, clean_record)
    w = dict(zip(replay.channels, replay.fit_weight, strict=True))
    assert w["theta_mcp_deg"] == 1.0
    floor = noise_floor(replay.measured["contact_force_n"])
    assert w["contact_force_n"] == pytest.approx(replay.scale[1] / (NOISY_SPREAD * floor))
    assert w["contact_force_n"] < 0.5
    sim = {c: replay.measured[c] + 0.1 * s for c, s in zip(replay.channels, replay.scale, strict=True)}
    r = replay.residual(sim, weighted=True)
    assert np.allclose(r[0], 0.1) and np.allclose(r[1], 0.1 * w["contact_force_n"])


def test_an_estimated_start_stays_in_the_range_the_drive_visits(cfg, independent_sma):
    """A session cut just before a heating, with a hidden dead zone the nominal model lacks: the
    first bend comes late, and an unbounded nuisance fit explained it with a wire at 15 C, below
    ambient (23 C), which no drive makes; the estimate stays within the states the replay visits."""
    from rehab_hil.discrepancy.initial_state import estimate_initial_state

    rec = independent_sma.sma_independent_record({"actuator_dead_zone": {"width_duty": 0.15}}, {}, 619, 20.0, 500.0)
    replay = Replay.build(get_plant("sma_exoskeleton"), cfg, rec)
    est = estimate_initial_state(replay, replay.nominal_params(), round(0.6 * replay.t.size))
    assert "sma_thermal.temperature_c" in est.estimated
    assert est.x0_of("sma_thermal.temperature_c") >= cfg.sma.ambient_c - 1.5


@pytest.mark.slow
def test_a_driver_dead_zone_beside_a_flexiforce_gain_is_fitted_to_its_width(cfg, independent_sma):
    """Dead zone 0.10 of full duty and a Flexiforce reading 15 % high, in a session cut while the wire
    is hot: the wire's temperature stays below the angle's threshold until the next heating, so the
    fits skip to it (``initial_state._memory``), and the force's count scatter does not outweigh the
    angle, so the width is the true one (measured before: 0.106 with a spurious contact damper, or
    0.074 with a viscous friction and an h1 +5 %). The gain moves this record's force (0-5 ADC counts)
    by under a count; named or not, nothing else is."""
    hidden = {"actuator_dead_zone": {"width_duty": 0.1},
              "sensor_gain_offset": {"gain_error_fraction": 0.15, "offset_counts": 0.0}}
    rec = independent_sma.sma_independent_record(hidden, {}, 624, 20.0, 500.0)
    res = find_missing_effects(cfg, rec, "dead_zone_gain.csv", options=Options())
    assert "actuator_dead_zone" in res.named and set(res.named) <= set(hidden), res.conclusion
    assert not res.parameters, res.conclusion
    fitted = {f.effect: f.params for f in res.chosen}
    assert fitted["actuator_dead_zone"]["width_duty"] == pytest.approx(0.1, rel=0.03)
    assert not res.unexplained, res.conclusion


@pytest.mark.slow
def test_hysteresis_and_a_passive_muscle_are_both_named_or_the_alias_is_said(cfg, independent_sma):
    """An 8 C hysteresis and a small passive muscle: the muscle stiffens the joint with angle like a
    contact spring does. The verdict names the hysteresis, and the muscle, saying plainly when the
    contact spring explains it about as well (issue 14 item 4). The muscle is fitted as a small scale
    with a steep shape; its torque over the motion, not its scale alone, makes it relevant."""
    hidden = {"sma_hysteresis": {"width_c": 8.0}, "passive_muscle": MUSCLE}
    rec = independent_sma.sma_independent_record(hidden, {}, 623, 20.0, 500.0)
    # two rounds, one per hidden effect: a third scored every candidate again and chose none (same
    # chosen, fitted values, aliases and conclusion)
    res = find_missing_effects(cfg, rec, "hysteresis_muscle.csv", options=Options(max_effects=2))
    assert "sma_hysteresis" in res.named, res.conclusion
    said = {frozenset((a.chosen, a.other)) for a in res.aliases}
    assert "passive_muscle" in res.named or (
        "contact_spring_damper" in res.named and frozenset(("contact_spring_damper", "passive_muscle")) in said
    ), res.conclusion
    fitted = {f.effect: f.params for f in res.chosen}
    assert fitted["sma_hysteresis"]["width_c"] == pytest.approx(8.0, rel=0.15)
    assert not res.unexplained, res.conclusion
