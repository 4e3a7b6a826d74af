"""One closed-loop session against the firmware itself, running in simavr behind the plant."""

from __future__ import annotations

import pytest

from rehab_hil.devices import avr_device
from rehab_hil.hardware import SerialHardware
from rehab_hil.service.session import open_session

from .conftest import CONFIG

pytestmark = [pytest.mark.slow, pytest.mark.firmware,
              pytest.mark.skipif(avr_device.unavailable_reason() is not None,
                                 reason=str(avr_device.unavailable_reason()))]


def test_the_model_based_step_on_the_firmware_in_simavr_reaches_the_target_and_ends_with_pwm_off(cfg, binding):
    # Virtual time (the harness's -k): the firmware's watchdog and the host's link budget are the
    # config's own, and the result does not depend on how loaded the machine is.
    with avr_device.spawn_avr_device(CONFIG, clock="lockstep") as dev:
        hw = SerialHardware(dev.port, resend_s=None)  # virtual time: a resend would cost device time
        hw.connect(timeout=10.0)
        try:
            with open_session(CONFIG, hw=hw, controller="model_based", reference="step", realtime=False,
                              sample_timeout_s=10.0, lockstep=True) as session:
                res = session.run(1.5)
        finally:
            hw.close()
    assert res.events == [], res.events
    assert res.sample_gaps == 0
    angle = res.final_sample.encoder_count * 360.0 / binding.encoder_counts_per_rev
    assert abs(angle - cfg.rig.session.step_deg) < 2.0
    assert res.pwm_off_at_end


def test_an_sma_session_learns_on_the_firmware_in_simavr_on_a_warmer_rig(tmp_path):
    # issue 39: the learning on the rig through the real firmware (lockstep: the same every run); the
    # device's plant is 7 C warmer than the host's model, so the model's table tracks worse there
    from rehab_hil.testing import CONFIGS

    sma = CONFIGS / "sma_exoskeleton.toml"
    warm = tmp_path / "warm.toml"
    text = sma.read_text()
    warm.write_text(text.replace("ambient_c = 23.0                    # T0", "ambient_c = 30.0  # T0", 1))
    with avr_device.spawn_avr_device(warm, clock="lockstep") as dev:
        hw = SerialHardware(dev.port, resend_s=None)
        hw.connect(timeout=10.0)
        try:
            with open_session(sma, hw=hw, realtime=False, sample_timeout_s=10.0, lockstep=True,
                              learning_store=tmp_path / "store") as session:
                res = session.run(30.0)
        finally:
            hw.close()
    assert res.events == [] and res.pwm_off_at_end, res.events
    rmse = [c["rmse_deg"] for c in res.session_cycles]
    assert [c["learn_trial"] for c in res.session_cycles] == [0.0, 1.0]
    assert rmse[0] > 2.0 and rmse[1] < 0.9 * rmse[0], rmse
