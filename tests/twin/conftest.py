"""Records as the loop hands them to the twin, made from a plant behind the rig's I/O (``PlantIO``)
and the host's own estimator: the twin's inputs without a serial link."""

from __future__ import annotations

from pathlib import Path
from types import SimpleNamespace
from typing import Any

import numpy as np

from rehab_hil.devices.plant_io import PlantIO
from rehab_hil.loading import load_config
from rehab_hil.loop.controllers import Command
from rehab_hil.loop.estimation import Estimator
from rehab_hil.loop.records import SampleRecord
from rehab_hil.plants.registry import get_plant
from rehab_hil.protocol import DUTY_FULL

CONFIGS = Path(__file__).resolve().parents[2] / "configs"


def plant_records(config: str | Path, duty: np.ndarray, seed: int = 0, keep: np.ndarray | None = None,
                  noise_counts: float = 0.0) -> tuple[Any, Any, list[Any]]:
    """(config, binding, records) of the plant driven by ``duty`` (0..1 per 1 ms tick, a signed
    effort's sign as the direction bit); ``keep``: which samples reach the twin (gaps)."""
    cfg = load_config(config)
    binding = get_plant(cfg.plant).device(cfg)
    io = PlantIO(binding, adc_noise_counts=noise_counts, seed=seed)
    est = Estimator(binding, 30.0)
    period = 1.0 / cfg.rig.sample_rate_hz
    records = []
    for k, d in enumerate(duty):
        direction = 1 if d < 0 else 0
        counts = round(float(abs(d)) * DUTY_FULL)
        enc, a0, a1 = io.tick((counts, 0), direction)
        state = est.update(enc, int(k * period * 1e6), (a0, a1))
        if keep is None or keep[k]:
            smp = SimpleNamespace(duty0=counts, duty1=0, direction=direction)
            records.append(SampleRecord(0.0, k * period, smp, state, Command(), k, float("nan")))
    return cfg, binding, records
