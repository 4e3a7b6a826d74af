"""A recorded session's tracking figures from its file (run.csv, else run.mcap): the same functions
the loop's summary calls (``metrics.recorded_tracking``, ``metrics.recorded_step``) on the same
rows, so a figure computed from the file is the figure the summary and metadata.json print.

A row's reference is the one of the command in force when its sample arrived; rows with none
(before the first command, the stop's rows) carry none and count in no figure."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from rehab_hil import metrics
from rehab_hil.interchange import CsvError
from rehab_hil.loop.run_dir import METADATA_FILE, read_metadata
from rehab_hil.rig_recording import read_recording
from rehab_hil.session_metrics import cycle_metrics

__all__ = ["angle_columns", "run_figures"]


def angle_columns(names: Any) -> tuple[str, str]:
    """(angle, reference) column names of a rig recording: ``<joint>_deg`` and ``<joint>_reference_deg``."""
    ref = next((n for n in names if n.endswith("_reference_deg")), None)
    if ref is None or ref.removesuffix("_reference_deg") + "_deg" not in names:
        raise ValueError("no angle and reference columns (<joint>_deg, <joint>_reference_deg): not a rig recording?")
    return ref.removesuffix("_reference_deg") + "_deg", ref


def run_figures(path: str | Path) -> dict[str, Any]:
    """``{"tracking": ..., "step_response": ..., "cycles": ...}`` of a run directory (or its run.csv /
    run.mcap): the step response for a step run, the open-close cycles' tracking figures for a
    session of cycles (its metadata's ``reference``), else None."""
    loaded = read_recording(path)
    rec = loaded.recording
    try:
        angle, ref = angle_columns(rec.signals)
    except ValueError as e:
        raise CsvError(loaded.source, 1, str(e)) from None
    meta = loaded.metadata
    if meta is None and (Path(path).parent / METADATA_FILE).is_file():  # run.csv or run.mcap named itself
        try:
            meta = read_metadata(Path(path).parent)
        except ValueError:  # unreadable: no step figures, the tracking still
            meta = None
    reference = (meta or {}).get("reference") or {}
    step = None
    if reference.get("kind") == "step":
        step = metrics.recorded_step(rec.t, rec[ref], rec[angle], start=float(reference["start_deg"])) or None
    return {"tracking": metrics.recorded_tracking(rec[ref], rec[angle]), "step_response": step,
            "cycles": _cycles(rec.t, rec[ref], rec[angle], reference) if reference.get("kind") == "session" else None}


def _cycles(t: np.ndarray, ref: np.ndarray, angle: np.ndarray, reference: dict[str, Any]) -> list[dict[str, float]]:
    """Each complete open-close cycle's tracking figures (``session_metrics.cycle_metrics``, as the
    loop's meter computes them on the same rows); the energy and temperature need the plant model
    and the loop's estimate: not here."""
    first = float(reference["first_open_s"])
    found = cycle_metrics(t - first, ref, angle, np.zeros(t.size), None, float(reference["period_s"]),
                          float(reference["move_s"]), float(reference["closed_deg"]), float(reference["open_deg"]))
    keys = ("index", "rmse_deg", "max_error_deg", "rom_deg", "time_to_open_s", "time_to_closed_s")
    return [{**{k: getattr(c, k) for k in keys}, "start_s": c.start_s + first} for c in found]
