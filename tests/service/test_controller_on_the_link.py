"""The declared controllers through the real loop when samples arrive in bursts, as behind the Uno's
USB bridge (2-3 at a time, the loop controlling once per burst): the seed 002 step is the same as
on a one-sample-per-command link, because the controller steps with dt from device time. The
in-process rig delivers the bursts deterministically, so a busy machine cannot change the answer;
bench/session_tracking.py measures the same behind the bridge model on a pty in real time."""

from __future__ import annotations

import pytest

from rehab_hil import metrics
from rehab_hil.interchange import read_csv
from rehab_hil.loop.recorder import Recorder
from rehab_hil.service.session import open_session
from rehab_hil.testing import inprocess_rig

from .conftest import CONFIG


def step_on(cfg, binding, tmp_path, controller: str, bursts: tuple[int, ...]) -> tuple[dict, object]:
    hw = inprocess_rig(CONFIG, configured=False, bursts=bursts)
    rec = Recorder(tmp_path / f"{controller}-{len(bursts)}", binding)
    try:
        with open_session(CONFIG, hw=hw, controller=controller, reference="step", sinks=(rec,),
                          realtime=False) as session:
            res = session.run(2.0)
    finally:
        rec.close()
        hw.close()
    run = read_csv(rec.csv_path)
    t = run["device_time_s"]
    return metrics.step_metrics(t - t[0], run["iris_angle_deg"], 0.0, cfg.rig.session.step_deg), res


@pytest.mark.parametrize("controller", ["pid", "model_based"])
def test_the_seed_002_step_is_the_same_with_samples_in_bursts_as_one_at_a_time(cfg, binding, tmp_path, controller):
    single, res_1 = step_on(cfg, binding, tmp_path, controller, (1,))
    bursty, res_b = step_on(cfg, binding, tmp_path, controller, (2, 2, 3))
    assert res_1.events == [] and res_b.events == [], (res_1.events, res_b.events)
    assert res_b.samples > 2 * res_b.cycles  # 2.33 samples per control step
    for m in (single, bursty):
        assert m["overshoot"] <= 2.86 and m["rise_time_s"] <= 0.3, (single, bursty)
    # with a constant dt in the PID the bursty step overshoots 1.26 deg more (this test then fails)
    assert abs(bursty["overshoot"] - single["overshoot"]) <= 0.5, (single, bursty)
    assert abs(bursty["rise_time_s"] - single["rise_time_s"]) <= 0.02, (single, bursty)
