"""Learning on the rig (issue 39 item 1), through ``open_session`` on the in-process rig: the
model-learned table is trial 0 and each cycle on a rig that differs from the model teaches the
next; the nominal rig keeps its figures; every update stays inside the safety envelope; the table
is kept per rig id, patient profile and plan and starts the next session there, nowhere else."""

from __future__ import annotations

import itertools
from pathlib import Path

import numpy as np
import pytest

from rehab_hil.controllers import build_controller
from rehab_hil.controllers.feedforward import ilc_step
from rehab_hil.controllers.limits import heating_limit_s
from rehab_hil.controllers.rig_learning import RigLearner, longest_run_s
from rehab_hil.loading import load_config
from rehab_hil.service.session import open_session
from rehab_hil.testing import CONFIGS, config_with_lines

pytestmark = [pytest.mark.slow, pytest.mark.timeout(600)]

SMA = CONFIGS / "sma_exoskeleton.toml"
EXAMPLE = CONFIGS.parent / "profiles" / "example.toml"


def rig(tmp_path: Path, old: str, new: str) -> Path:
    """The shipped SMA config with one value changed: the simulated rig's plant (``--sim-plant``)."""
    return config_with_lines(SMA, tmp_path / "rig.toml", {old: new})


def rmse_per_cycle(sim: Path | None, learning: bool, store: Path, duration_s: float = 100.0, **kw) -> list[float]:
    with open_session(SMA, "inprocess", sim_plant=sim, rig_learning=learning, learning_store=store, **kw) as s:
        r = s.run(duration_s)
    assert r.events == [], r.events
    return [c["rmse_deg"] for c in r.session_cycles]


def test_learning_lowers_a_warm_rooms_error_cycle_after_cycle_and_keeps_the_nominal_rigs(tmp_path: Path) -> None:
    warm = rig(tmp_path, "ambient_c = 23.0                    # T0", "ambient_c = 30.0  # T0")
    fixed = rmse_per_cycle(warm, False, tmp_path / "a")
    learned = rmse_per_cycle(warm, True, tmp_path / "b")
    assert len(learned) >= 7
    assert learned[0] == pytest.approx(fixed[0], abs=0.02)  # trial 0: the model's table
    assert all(b < a for a, b in itertools.pairwise(learned[:5])), learned  # falls cycle after cycle
    assert max(learned[3:]) < 0.75 * min(fixed[3:]), (learned, fixed)
    nominal_fixed = rmse_per_cycle(None, False, tmp_path / "c")
    nominal = rmse_per_cycle(None, True, tmp_path / "d")
    assert max(nominal) <= max(nominal_fixed) + 0.03, (nominal, nominal_fixed)


def test_an_update_that_would_leave_the_envelope_is_kept_inside_it() -> None:
    cfg = load_config(SMA)
    ctl = build_controller(cfg, check=False)
    spec = ctl.rig_learning
    table = np.asarray(next(iter(ctl.plan.signals.values())), float)
    learner = RigLearner(spec, table)
    error = np.full(spec.n, 30.0)  # the angle 30 deg short all cycle: an unconstrained update heats throughout
    effort = np.clip(table, *spec.bounds)
    free = ilc_step(table, error, spec.step_s, spec.bounds, spec.learning, True, spec.gain_per_deg)
    assert longest_run_s(free, spec.step_s) > heating_limit_s(ctl.ctx)  # it would heat past the limit ...
    assert learner.predicted_peak_c(free) > spec.budget_c  # ... and past the temperature budget
    new, info = learner.update(table, error, effort)
    lo, hi = spec.bounds
    assert new.min() >= lo and new.max() <= hi
    assert longest_run_s(new, spec.step_s) <= heating_limit_s(ctl.ctx)
    assert info["learn_share"] < 1.0 and info["learn_predicted_peak_c"] <= spec.budget_c
    assert learner.predicted_peak_c(effort + (new - table)) <= spec.budget_c + 0.5
    assert np.mean(new) > np.mean(table)  # it still learned what it could: more effort


def test_the_learned_table_starts_the_next_session_on_the_same_rig_and_profile_only(tmp_path: Path) -> None:
    store = tmp_path / "store"

    def session(rig_id: str, profile: Path | None = None, duration_s: float = 20.0) -> dict:
        with open_session(SMA, "inprocess", rig_id=rig_id, profile=profile, learning_store=store) as s:
            r = s.run(duration_s)
            table = s.controller.learned_table.copy()
        assert r.events == [], r.events
        return {**r.learning, "table": table}

    first = session("rig-a")
    assert first["updates"] == 1 and not first["resumed"] and Path(first["store"]).exists()
    again = session("rig-a", duration_s=5.0)
    assert again["resumed"] and again["trials"] == 1
    np.testing.assert_array_equal(again["table"], first["table"])
    other = session("rig-b", duration_s=5.0)
    assert not other["resumed"] and other["trials"] == 0
    with_profile = session("rig-a", EXAMPLE, duration_s=5.0)
    assert not with_profile["resumed"] and with_profile["store"] != first["store"]


class StopAfter:
    """A sink that asks the loop to stop (a trip, as an operator's stop request is) past ``t_s``."""

    name, critical, dropped, error, on_failure = "stop-after", False, 0, None, None

    def __init__(self, t_s: float) -> None:
        self.t_s, self.session = t_s, None

    def offer(self, record) -> bool:
        t = getattr(record, "time_s", None)
        if t is not None and t > self.t_s and self.session is not None:
            self.session.request_stop("the test's stop")
        return True

    def wake(self) -> None: ...

    def drain(self) -> None: ...

    def close(self) -> None: ...


def test_a_session_that_ends_in_a_safety_trip_leaves_the_store_as_it_found_it(tmp_path: Path) -> None:
    store = tmp_path / "store"
    stop = StopAfter(16.0)  # after the first update (swapped in at 14.4 s)
    with open_session(SMA, "inprocess", rig_id="rig-t", learning_store=store, sinks=(stop,)) as s:
        stop.session = s
        r = s.run(30.0)
    assert r.events and r.learning["updates"] == 1 and not r.learning["kept"]
    assert not Path(r.learning["store"]).exists()  # nothing was stored before: nothing is


def test_an_error_within_one_encoder_count_teaches_nothing_and_a_motor_table_held_throughout_keeps_its_hold() -> None:
    """Below a count the encoder cannot tell better from worse; and a motor's table that is on all
    period (it holds against the spring) gets no planted rest: one planted per cycle dipped the
    Finger Extensor's closed hold (nominal rig 0.054 -> 0.10 deg RMSE with learning on)."""
    cfg = load_config(CONFIGS / "finger_extensor.toml")
    ctl = build_controller(cfg, check=False)
    spec = ctl.rig_learning
    count_deg = 360.0 / ctl.ctx.binding.encoder_counts_per_rev
    assert spec.deadband_deg == pytest.approx(count_deg)
    table = np.asarray(next(iter(ctl.plan.signals.values())), float)
    learner = RigLearner(spec, table)
    flicker = np.where(np.arange(spec.n) % 2 == 0, 0.9, -0.9) * count_deg
    new, flickered = learner.update(table, flicker, np.clip(table, *spec.bounds))
    _, real = learner.update(table, np.full(spec.n, 3.0 * count_deg), np.clip(table, *spec.bounds))
    assert flickered["learn_error_rmse_deg"] > 0.0
    assert flickered["learn_change_rms"] < 0.02 * real["learn_change_rms"]  # a real error still teaches
    assert np.count_nonzero(new == 0.0) == np.count_nonzero(table == 0.0)  # no rest planted into the hold
