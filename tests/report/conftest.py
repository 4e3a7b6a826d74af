"""Synthetic run directories with known answers: the recorder's file layout (metadata.json,
run.csv with its column names) holding signals whose per-cycle peak force, range of motion and
events the tests know."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest

from rehab_hil.loop.run_dir import write_metadata

PERIOD_S = 4.0
FIRST_OPEN_S = 1.0
RATE_HZ = 250.0  # the report does not care about the rate; fewer rows keep the tests quick


def write_run(root: Path, name: str, *, rom_deg: float = 30.0, peak_forces: tuple[float, ...] = (1.0, 2.0, 3.0),
              start: str = "2026-11-01T09:00:00.000+00:00", events: list[dict] | None = None,
              ended: bool = True, plant: str = "sma_exoskeleton", requested_s: float | None = None,
              sensor: tuple[str, str, str] = ("contact_force_n", "force", "n"), flat_sensor: bool = False) -> Path:
    """A run with one cycle per peak force: the angle rises to ``rom_deg`` and back in each cycle,
    the force peaks at the given value once per cycle. ``requested_s``: written as today's recorder
    does (the rows after the stop, the first event or the record's end, with an empty reference;
    ``duration_s`` the time it ran); without it, as before (0 deg there, ``duration_s`` as asked).
    ``sensor``: the ADC signal's (name, kind, unit); ``flat_sensor``: it reads 0 throughout."""
    d = root / name
    d.mkdir(parents=True)
    n_cycles = len(peak_forces)
    t = np.arange(0.0, FIRST_OPEN_S + n_cycles * PERIOD_S + 0.5, 1.0 / RATE_HZ)
    phase = np.clip(t - FIRST_OPEN_S, 0.0, None) % PERIOD_S
    active = (t >= FIRST_OPEN_S) & (t < FIRST_OPEN_S + n_cycles * PERIOD_S)
    reference = np.where(active, rom_deg * np.sin(math.pi * phase / PERIOD_S) ** 2, 0.0)
    angle = reference + 0.1 * np.sin(7.0 * t)
    force = np.zeros_like(t)
    for k, peak in enumerate(peak_forces):
        force[int((FIRST_OPEN_S + k * PERIOD_S + 1.3) * RATE_HZ)] = peak  # one spike per cycle
    temp = 25.0 + 10.0 * reference / max(rom_deg, 1e-9)
    duty = np.clip(reference / max(rom_deg, 1e-9), 0.0, 1.0)
    stop = (events[0]["t_s"] if events else float(t[-1]) - 0.1) if requested_s is not None else None
    if stop is not None:
        reference = np.where(t > stop, np.nan, reference)
    cols = {"time_s": t, "theta_mcp_rad": np.radians(angle), "theta_mcp_deg": angle,
            "theta_mcp_reference_deg": reference, sensor[0]: 0.0 * force if flat_sensor else force, "pwm_duty": duty,
            "applied_duty0_ratio": duty, "applied_duty1_ratio": np.zeros_like(t), "estimated_temperature_c": temp}
    lines = [",".join(cols)] + [",".join("" if v != v else f"{v:.10g}" for v in row)
                                for row in zip(*cols.values(), strict=True)]
    (d / "run.csv").write_text("\n".join(lines) + "\n")
    cycles = [{"index": k, "start_s": FIRST_OPEN_S + k * PERIOD_S, "rmse_deg": 0.07, "max_error_deg": 0.1,
               "rom_deg": rom_deg, "time_to_open_s": 1.5, "time_to_closed_s": 1.5, "peak_temperature_c": 35.0,
               "energy_j": 10.0 + k} for k in range(n_cycles)]
    meta = {"plant": plant, "config_path": "configs/sma_exoskeleton.toml", "config_sha256": "ab" * 32,
            "config_text": "[rig.session]\ncycles_per_minute = 15.0\n", "sim_plant": None,
            "device": {"kind": "inprocess", "port": None},
            "firmware": {"name": "rehab_fw", "version": "9.8.7", "protocol_version": 1}, "rig_id": "bench7",
            "controller": "model_based", "pacing": "device",
            "calibration": {"encoder_counts_per_rev": 4096,
                            "adc": [{"signal": sensor[0], "source": "adc0", "kind": sensor[1], "unit": sensor[2],
                                     "counts_per_unit": 20.0, "offset_counts": 0.0}]},
            "start_time_utc": start}
    if ended:
        meta |= {"end_time_utc": start, "duration_s": float(t[-1]) if stop is None else stop,
                 "stop_reason": f"safety trip: {events[0]['reason']}" if events else "duration reached",
                 "rows": int(t.size), "samples": int(t.size), "sample_gaps": 0, "pwm_off_at_end": True,
                 "tracking": {"rmse": 0.07, "max_abs_error": 0.1}, "safety_events": events or [],
                 "session": {"cycles": float(n_cycles), "rmse_deg": 0.07, "rom_deg": rom_deg,
                             "energy_per_cycle_j": 11.0},
                 "session_cycles": cycles}
    if ended and requested_s is not None:
        meta["requested_duration_s"] = requested_s
    write_metadata(d, meta)
    json.loads((d / "metadata.json").read_text())
    return d


@pytest.fixture
def make_run():
    return write_run
