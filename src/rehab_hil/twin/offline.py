"""The twin on a recorded session: the same computation as live, fed from ``run.csv``.

A run directory holds what the loop handed the twin: the applied duties and direction bits the
device reported, the estimated angle and the calibrated ADC signals of every sample. Replaying them
through ``Twin`` gives the residuals and events the live twin would have given (``rehab-hil twin``),
so a session recorded without the twin, or with other settings, can be judged afterwards.
"""

from __future__ import annotations

import math
from pathlib import Path
from types import SimpleNamespace
from typing import Any

import numpy as np

from rehab_hil.interchange import CsvError, read_csv
from rehab_hil.interfaces import DeviceBinding
from rehab_hil.protocol import DUTY_FULL
from rehab_hil.twin.live import Twin

__all__ = ["records_of_run", "replay_run"]


def records_of_run(csv_path: str | Path, binding: DeviceBinding) -> list[Any]:
    """The loop's sample records of a ``run.csv``, as the twin reads them."""
    rec = read_csv(csv_path)
    cols = ["applied_duty0_ratio", "applied_duty1_ratio", "direction_bits"]
    missing = [c for c in [*cols, binding.angle_output] if c not in rec.signals]
    if missing:
        raise CsvError(csv_path, 1, f"not a rig recording (run.csv): missing columns {missing}")
    d0 = np.rint(rec["applied_duty0_ratio"] * DUTY_FULL).astype(int)
    d1 = np.rint(rec["applied_duty1_ratio"] * DUTY_FULL).astype(int)
    dirs = rec["direction_bits"].astype(int)
    angle = rec[binding.angle_output]
    analog = {a.signal: rec[a.signal] for a in binding.adc if a.signal in rec.signals}
    out = []
    for k in range(rec.t.size):
        smp = SimpleNamespace(duty0=int(d0[k]), duty1=int(d1[k]), direction=int(dirs[k]))
        st = SimpleNamespace(angle_deg=float(angle[k]), analog={s: float(v[k]) for s, v in analog.items()})
        out.append(SimpleNamespace(time_s=float(rec.t[k]), sample=smp, state=st))
    return out


def replay_run(twin: Twin, csv_path: str | Path) -> Twin:
    """Feed a recorded session through ``twin`` (diagnoses run in line); returns it, finished."""
    for r in records_of_run(csv_path, twin.binding):
        if math.isfinite(r.time_s):
            twin.feed(r)
    twin.finish()
    return twin
