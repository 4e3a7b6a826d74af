"""A recorded run as the report needs it: metadata.json, the few columns it plots, safety events
and per-cycle figures (``metadata.json``'s ``session_cycles``, with the peak force of each cycle
added from the record).

``find_runs`` turns what a user typed (a run directory, its run.csv / run.mcap, or the ``--record``
folder holding several runs) into run directories, oldest first.
"""

from __future__ import annotations

import math
import tomllib
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from rehab_hil.interchange import CsvError
from rehab_hil.loop.run_dir import METADATA_FILE, RUN_FILES, is_run_dir, read_metadata

__all__ = ["ReportError", "RunData", "find_runs", "load_run"]

class ReportError(Exception):
    """A run that cannot be reported: one line naming the file."""


@dataclass
class RunData:
    """One run: identity, the plotted columns (full rate) and the per-cycle table."""

    path: Path
    meta: dict[str, Any]
    t: np.ndarray
    angle_name: str
    angle: np.ndarray
    reference: np.ndarray  # NaN where no reference was tracked (before the first command, after the stop)
    sensors: dict[str, np.ndarray]  # calibrated ADC signals (force, torque ...) that vary, by name
    temperature: np.ndarray | None  # estimated actuator temperature; None when the rig has none
    duty: dict[str, np.ndarray]
    events: list[dict[str, Any]]  # {"t_s", "reason", "detail"}
    cycles: list[dict[str, float]]  # session_cycles + peak_force and end_s
    period_s: float
    notes: list[str] = field(default_factory=list)
    flat_sensors: dict[str, float] = field(default_factory=dict)  # sensors that read one value throughout
    sensor_info: dict[str, dict[str, Any]] = field(default_factory=dict)  # metadata's ADC calibration by signal

    @property
    def label(self) -> str:
        return self.path.name

    @property
    def sensor_name(self) -> str | None:
        """The first sensor that varies (its per-cycle peak is in the table), or None."""
        return next(iter(self.sensors), None)

    @property
    def angle_resolution_deg(self) -> float | None:
        """One encoder count [deg] (metadata's calibration), or None when unknown."""
        cpr = (self.meta.get("calibration") or {}).get("encoder_counts_per_rev")
        return 360.0 / cpr if isinstance(cpr, int | float) and cpr > 0 else None

    def sensor_resolution(self, name: str) -> float | None:
        """One ADC count in the sensor's unit, or None when unknown."""
        per = self.sensor_info.get(name, {}).get("counts_per_unit")
        return 1.0 / abs(per) if isinstance(per, int | float) and per else None



def find_runs(path: str | Path) -> list[Path]:
    """The run directories ``path`` names: itself (or the directory of its run.csv / run.mcap), or
    every run directory directly inside it, oldest first (their names start with the UTC time)."""
    p = Path(path)
    if p.is_file() and p.name in RUN_FILES:
        if not is_run_dir(p.parent):
            raise ReportError(f"{p}: not in a run directory (no {METADATA_FILE} beside it; `rehab-hil run --record "
                              "DIR` writes one per session; a `simulate --out` CSV has no session to report)")
        return [p.parent]
    if not p.exists():
        raise ReportError(f"{p}: no such file or directory")
    if not p.is_dir():
        raise ReportError(f"{p}: not a run directory (give the folder of run.csv, run.mcap and metadata.json)")
    if is_run_dir(p):
        return [p]
    runs = sorted(d for d in p.iterdir() if is_run_dir(d))
    if not runs:
        raise ReportError(f"{p}: no run here (a run directory holds run.csv, run.mcap and metadata.json; "
                          "`rehab-hil run --record DIR` writes one per session under DIR)")
    return runs


def _read_columns(path: Path, wanted: list[str]) -> dict[str, np.ndarray]:
    """``wanted`` columns of a recorder CSV (missing ones absent); a last line cut short by a kill
    is dropped."""
    import pandas as pd

    try:
        with path.open("rb") as fh:
            header = fh.readline().decode("utf-8", "replace").strip().split(",")
            fh.seek(0, 2)
            size = fh.tell()
            fh.seek(max(0, size - 1))
            ends_clean = fh.read(1) == b"\n"
        cols = [c for c in wanted if c in header]
        df = pd.read_csv(path, usecols=cols, dtype=float, engine="c", on_bad_lines="skip")
    except (OSError, ValueError, pd.errors.ParserError) as e:
        raise ReportError(f"{path}: unreadable: {e}") from None
    if not ends_clean and len(df):
        df = df.iloc[:-1]
    return {c: df[c].to_numpy() for c in cols}


def _read_mcap_columns(path: Path) -> dict[str, np.ndarray]:
    from rehab_hil.rig_recording import read_mcap_recording

    try:
        rec, _ = read_mcap_recording(path)
    except CsvError as e:
        raise ReportError(str(e)) from None
    return {"time_s": rec.t, **rec.signals}


def _period_s(meta: dict[str, Any], cycles: list[dict[str, Any]]) -> float:
    starts = [c["start_s"] for c in cycles]
    if len(starts) >= 2:
        return float(np.median(np.diff(starts)))
    try:
        cpm = tomllib.loads(meta.get("config_text", ""))["rig"]["session"]["cycles_per_minute"]
        return 60.0 / float(cpm)
    except (tomllib.TOMLDecodeError, KeyError, TypeError, ValueError, ZeroDivisionError):
        return math.nan


def load_run(run_dir: str | Path) -> RunData:
    """Read a run directory for the report (``ReportError`` names the file when it cannot)."""
    run_dir = Path(run_dir)
    try:
        meta = read_metadata(run_dir)
    except ValueError as e:
        raise ReportError(str(e)) from None
    notes: list[str] = []
    csv, mcap = run_dir / "run.csv", run_dir / "run.mcap"
    info = {a["signal"]: a for a in (meta.get("calibration") or {}).get("adc", []) if "signal" in a}
    forces = list(info)
    if csv.is_file():
        with csv.open("rb") as fh:
            header = fh.readline().decode("utf-8", "replace").strip().split(",")
        refs = [c for c in header if c.endswith("_reference_deg")]
        wanted = ["time_s", *refs, *(r.removesuffix("_reference_deg") + "_deg" for r in refs), *forces,
                  "estimated_temperature_c", "applied_duty0_ratio", "applied_duty1_ratio"]
        cols = _read_columns(csv, wanted)
    elif mcap.is_file():
        cols = _read_mcap_columns(mcap)
    else:
        raise ReportError(f"{run_dir}: no run.csv or run.mcap (a run that recorded nothing?)")
    t = cols.get("time_s")
    if t is None or t.size == 0:
        raise ReportError(f"{csv if csv.is_file() else mcap}: no samples recorded")
    keep = np.concatenate([[True], np.diff(t) > 0])  # strictly increasing time
    cols = {k: v[keep] for k, v in cols.items()}
    ref_name = next((c for c in cols if c.endswith("_reference_deg")), None)
    angle_name = ref_name.removesuffix("_reference_deg") + "_deg" if ref_name else None
    if angle_name is None or angle_name not in cols:
        raise ReportError(f"{csv if csv.is_file() else mcap}: no angle and reference columns "
                          "(<joint>_deg, <joint>_reference_deg): not a rig recording?")
    temp = cols.get("estimated_temperature_c")
    if temp is not None and not np.any(temp != temp[0]):
        temp = None  # a rig without a temperature estimate records a constant
    duty = {k: cols[k] for k in ("applied_duty0_ratio", "applied_duty1_ratio") if k in cols and np.any(cols[k])}
    if not duty and "applied_duty0_ratio" in cols:
        duty = {"applied_duty0_ratio": cols["applied_duty0_ratio"]}
    if "end_time_utc" not in meta:
        notes.append(f"{run_dir / METADATA_FILE}: no end record (the run was killed?): no per-cycle figures "
                     "or safety events")
    events = list(meta.get("safety_events") or [])
    cycles = [dict(c) for c in meta.get("session_cycles") or []]
    period = _period_s(meta, cycles)
    t = cols["time_s"]
    sensors = {f: cols[f] for f in forces if f in cols}
    flat = {f: float(v[0]) for f, v in sensors.items() if not np.any(v != v[0])}
    sensors = {f: v for f, v in sensors.items() if f not in flat}
    force_sig = next(iter(sensors.values()), None)
    reference = _without_stop_rows(meta, t, cols[ref_name])
    for c in cycles:
        c["end_s"] = c["start_s"] + period
        sel = (t >= c["start_s"]) & (t < c["end_s"])
        c["peak_force"] = float(np.max(force_sig[sel])) if force_sig is not None and sel.any() else math.nan
    return RunData(path=run_dir, meta=meta, t=t, angle_name=angle_name, angle=cols[angle_name], reference=reference,
                   sensors=sensors, temperature=temp, duty=duty, events=events, cycles=cycles, period_s=period,
                   notes=notes, flat_sensors=flat, sensor_info=info)


def _without_stop_rows(meta: dict[str, Any], t: np.ndarray, reference: np.ndarray) -> np.ndarray:
    """The reference with its stop rows empty: a run recorded before they were written empty
    (no ``requested_duration_s`` in its metadata) carries 0 deg there, which is no release."""
    if "requested_duration_s" in meta or "end_time_utc" not in meta:
        return reference
    events = meta.get("safety_events") or []
    stop = events[0].get("t_s") if events else meta.get("duration_s")
    if not isinstance(stop, int | float):
        return reference
    after = t > stop if events else t >= stop - 1e-9  # a trip's own row may still carry its command
    return np.where(after, np.nan, reference)
