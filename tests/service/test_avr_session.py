"""One closed-loop session against the firmware itself, running in simavr behind the plant."""

from __future__ import annotations

import dataclasses

import pytest

from rehab_hil.devices import avr_device
from rehab_hil.hardware import SerialHardware
from rehab_hil.service import assembly
from rehab_hil.service.runner import LoopService
from rehab_hil.service.supervisor import Supervisor

from .conftest import CONFIG

pytestmark = [pytest.mark.slow, pytest.mark.firmware,
              pytest.mark.skipif(avr_device.unavailable_reason() is not None,
                                 reason=str(avr_device.unavailable_reason()))]


def test_the_model_based_step_on_the_firmware_in_simavr_reaches_the_target_and_ends_with_pwm_off(cfg, binding):
    # simavr runs in real time on a shared VM: the watchdog and link-loss budgets are widened so
    # that scheduler stalls of the test machine do not end the session; the control is unchanged.
    conf = dataclasses.replace(assembly.firmware_configure(cfg, binding), watchdog_ms=500)
    base = assembly.build_supervisor(cfg, binding)
    sup = Supervisor(dataclasses.replace(base.limits, link_loss_periods=500), base.dt_s, base.force_signals,
                     base.thermal)
    with avr_device.spawn_avr_device(CONFIG, clock="realtime") as dev:
        hw = SerialHardware(dev.port)
        hw.connect()
        try:
            svc = LoopService(hw, conf, assembly.build_controller(cfg, "model_based", "step"),
                              assembly.build_estimator(cfg, binding), sup, assembly.period_s(cfg))
            res = svc.run(1.5, pacing="device", realtime=True)
        finally:
            hw.close()
    assert res.events == [], res.events
    angle = res.final_sample.encoder_count * 360.0 / binding.encoder_counts_per_rev
    assert abs(angle - cfg.rig.session.step_deg) < 2.0
    assert res.pwm_off_at_end
