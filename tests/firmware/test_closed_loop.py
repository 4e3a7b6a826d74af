"""Closed loop: the firmware in simavr drives the Finger Extensor plant (PlantIO, the same model
as the Python device) and reads it back through real quadrature edges and the ADC. The encoder
counts the firmware reports must follow the plant: replaying the applied duties (from the
SAMPLEs) through an independent PlantIO gives the same trajectory."""

from __future__ import annotations

import pytest

from rehab_hil.devices.plant_io import PlantIO
from rehab_hil.loading import load_config
from rehab_hil.plants import get_plant
from rehab_hil.protocol import CommandFrame, Sample

from .conftest import ROOT, Hardware, _missing, config

pytestmark = [pytest.mark.firmware, pytest.mark.slow, pytest.mark.timeout(180)]

CONFIG = ROOT / "configs" / "finger_extensor.toml"


def test_encoder_count_follows_the_plant() -> None:
    reason = _missing()
    if reason:
        pytest.skip(reason)
    from rehab_hil.devices.avr_device import spawn_avr_device

    samples: list[Sample] = []
    with spawn_avr_device(CONFIG, clock="lockstep") as dev:  # virtual time: one COMMAND a sample
        hw = Hardware(dev.port, resend_s=None)  # virtual time: a resend would cost device time
        try:
            hw.connect(timeout=10.0)
            hw.configure(config(watchdog_ms=300))
            hw.discard_pending()
            while len(samples) < 600:  # 40 % forward, then 40 % reversed (H-bridge)
                hw.send_command(CommandFrame(4000, 0, 1 if len(samples) >= 300 else 0, 1))
                s = hw.read_sample(10.0)
                assert s is not None, dev.control("status")
                samples.append(s)
            status = dev.control("status")
        finally:
            hw.close()
    assert all(s.faults == 0 for s in samples), status
    assert len(samples) == 600
    # Replay the applied duty, tick by tick, through a fresh plant. The device's plant ran with
    # duty 0 from boot until the first command, at rest, so the replay starts at the first sample.
    cfg = load_config(CONFIG)
    plant = PlantIO(get_plant(cfg.plant).device(cfg))
    by_index = {s.sample_index: s for s in samples}
    first, last = samples[0].sample_index, samples[-1].sample_index
    enc0 = samples[0].encoder_count
    errors, travel, replay_adc = [], 0, []
    prev = samples[0]
    for i in range(first, last + 1):
        s = by_index.get(i, prev)  # a sample the host missed: the duty held
        enc, a0, _ = plant.tick((s.duty0, s.duty1), s.direction)
        replay_adc.append(a0)
        if i in by_index:
            # the firmware's count lags the plant by the lockstep tick and the edge spacing
            errors.append(abs((s.encoder_count - enc0) - enc))
            travel = max(travel, abs(s.encoder_count - enc0))
        prev = s
    assert travel > 50, f"the finger hardly moved ({travel} counts): {status}"
    assert max(errors) <= max(6, 0.05 * travel), (max(errors), travel)
    # it went forward, then back
    peak = max(samples, key=lambda s: s.encoder_count)
    assert peak.encoder_count > enc0 + 50 and samples[-1].encoder_count < peak.encoder_count
    # the torque sensor on A0 (through simavr's ADC) spans the plant's drive torque range
    dev_adc = [s.adc0 for s in samples]
    for dev_x, rep_x in ((min(dev_adc), min(replay_adc)), (max(dev_adc), max(replay_adc))):
        assert abs(dev_x - rep_x) <= 0.1 * (max(replay_adc) - min(replay_adc)), (dev_x, rep_x)
