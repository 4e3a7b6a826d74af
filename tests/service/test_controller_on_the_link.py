"""The declared controllers through the real loop on a pseudo-terminal: the seed 002 step behaves
the same behind the Uno's USB bridge (samples in bursts of 2-4, the loop controlling once per
burst) as on a direct link, because the controller steps with dt from device time."""

from __future__ import annotations

import pytest

from rehab_hil import metrics
from rehab_hil.devices import spawn_device
from rehab_hil.hardware import SerialHardware
from rehab_hil.interchange import read_csv
from rehab_hil.service import assembly
from rehab_hil.service.recorder import Recorder
from rehab_hil.service.runner import LoopService

from .conftest import CONFIG

pytestmark = [pytest.mark.slow, pytest.mark.xdist_group("realtime-link")]


def step_on(cfg, binding, tmp_path, controller: str, bridge: bool) -> tuple[dict, object]:
    with spawn_device("sim", CONFIG, clock="realtime", usb_bridge=bridge) as dev:
        hw = SerialHardware(dev.port)
        hw.connect(timeout=15.0)  # behind the bridge: the bootloader's second first
        rec = Recorder(tmp_path / f"{controller}-{bridge}", binding)
        try:
            svc = LoopService(hw, assembly.firmware_configure(cfg, binding),
                              assembly.build_controller(cfg, controller, "step"),
                              assembly.build_estimator(cfg, binding), assembly.build_supervisor(cfg, binding),
                              assembly.period_s(cfg), recorder=rec)
            res = svc.run(2.0, pacing="device", realtime=True)
        finally:
            rec.close()
            hw.close()
    run = read_csv(rec.csv_path)
    t = run["device_time_s"]
    return metrics.step_metrics(t - t[0], run["iris_angle_deg"], 0.0, cfg.rig.session.step_deg), res


@pytest.mark.parametrize("controller", ["pid", "model_based"])
def test_the_seed_002_step_is_the_same_behind_the_usb_bridge_as_direct(cfg, binding, tmp_path, controller):
    direct, res_d = step_on(cfg, binding, tmp_path, controller, bridge=False)
    bridged, res_b = step_on(cfg, binding, tmp_path, controller, bridge=True)
    assert res_d.events == [] and res_b.events == [], (res_d.events, res_b.events)
    assert res_b.samples > 1.5 * res_b.cycles  # the bridge delivered bursts: fewer control steps than samples
    for m in (direct, bridged):
        assert m["overshoot"] <= 2.86 and m["rise_time_s"] <= 0.3, (direct, bridged)
    assert abs(bridged["overshoot"] - direct["overshoot"]) <= 0.5, (direct, bridged)  # constant dt: 1.26 deg apart
    assert abs(bridged["rise_time_s"] - direct["rise_time_s"]) <= 0.03, (direct, bridged)
