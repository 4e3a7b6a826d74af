"""The model loop closed live (issue 39 item 2): when the twin finds a thermal quantity beyond its
interval, the feedforward is re-planned on the model with the estimate and the learning on the rig
takes it at a cycle boundary; the event says so."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from rehab_hil.controllers import build_controller
from rehab_hil.loading import load_config
from rehab_hil.plants.changes import with_values
from rehab_hil.service.rig_learning import RigLearning
from rehab_hil.service.session import open_session
from rehab_hil.testing import CONFIGS

SMA = CONFIGS / "sma_exoskeleton.toml"


def sma_learning() -> tuple[RigLearning, np.ndarray]:
    ctl = build_controller(load_config(SMA), check=False)
    table = np.asarray(next(iter(ctl.plan.signals.values())), float)
    return RigLearning(ctl.rig_learning, table, store=None, lockstep=True), table


def test_a_model_updated_on_estimates_is_validated_like_a_config() -> None:
    cfg = load_config(SMA)
    warm = with_values(cfg, {"sma.ambient_c": 30.0, "drive.supply_voltage_v": 28.8})
    assert (warm.sma.ambient_c, warm.drive.supply_voltage_v) == (30.0, 28.8)
    assert cfg.sma.ambient_c == 23.0  # the session's own config is not changed
    with pytest.raises(ValueError):
        with_values(cfg, {"sma.ambient_c": 400.0})  # beyond the key's range: refused as a config is


def test_a_rebased_table_is_taken_at_the_next_swap_point_and_becomes_what_the_forgetting_pulls_toward() -> None:
    learning, table = sma_learning()
    try:
        spec = learning.spec
        new = np.clip(table * 0.9, *spec.bounds)
        learning.expect_rebase()
        learning.rebase(new, {"replan_updates": {"sma.ambient_c": 30.0}, "replan_s": 1.0})
        assert learning.record(0.1, 0, 0.0, 0.0) is None  # not before the swap point
        taken = learning.record(spec.swap_s, 0, 0.0, 0.0)
        assert taken is not None and np.allclose(taken, learning.learner.fit(new))
        assert np.allclose(learning.learner.base, taken) and learning.table is taken
        entry = learning.log[-1]
        assert entry["learn_replanned"] == 1.0 and entry["replan_updates"] == {"sma.ambient_c": 30.0}
        assert learning.summary()["replans"] == [entry] and learning.summary()["updates"] == 0
    finally:
        learning.close()


def test_a_failed_replan_leaves_the_table_and_says_why() -> None:
    learning, table = sma_learning()
    try:
        learning.expect_rebase()
        learning.rebase(None, {"replan_error": "ValueError: no"})
        assert learning.record(learning.spec.swap_s, 0, 0.0, 0.0) is None
        assert learning.table is not None and np.allclose(learning.table, table)
        assert learning.summary()["replans"][0]["replan_error"] == "ValueError: no"
    finally:
        learning.close()


@pytest.mark.slow
@pytest.mark.timeout(600)
def test_a_warm_rooms_estimate_replans_the_feedforward_during_the_session(tmp_path: Path) -> None:
    text = SMA.read_text()
    old = "ambient_c = 23.0                    # T0"
    assert old in text
    warm = tmp_path / "warm.toml"
    warm.write_text(text.replace(old, "ambient_c = 30.0  # T0", 1))
    with open_session(SMA, "inprocess", sim_plant=warm, twin=True, rig_learning=True,
                      learning_store=tmp_path / "store") as s:
        r = s.run(40.0)
    assert r.events == [], r.events
    events = r.twin["twin"]["thermal"]["events"]
    ambient = [e for e in events if e["key"] == "sma.ambient_c"]
    assert ambient and abs(ambient[0]["value"] - 30.0) < 2.0, events
    assert "re-planned" in ambient[0]["action"], ambient[0]
    replans = r.learning["replans"]
    assert replans and "replan_error" not in replans[0], replans
    assert abs(replans[0]["replan_updates"]["sma.ambient_c"] - 30.0) < 2.0
    assert replans[0]["t_s"] < 40.0  # taken in this session, at a cycle boundary
    cycles = [c for c in r.session_cycles if c.get("learn_replanned")]
    assert cycles, r.session_cycles  # the cycle it was taken in says so
