"""A recorded session's tracking figures from its file (run.csv, else run.mcap): the same functions
the loop's summary calls (``metrics.recorded_tracking``, ``metrics.recorded_step``) on the same
rows, so a figure computed from the file is the figure the summary and metadata.json print.

A row's reference is the one of the command in force when its sample arrived; rows with none
(before the first command, the stop's rows) carry none and count in no figure."""

from __future__ import annotations

from pathlib import Path
from typing import Any

from rehab_hil import metrics
from rehab_hil.interchange import CsvError
from rehab_hil.rig_recording import read_recording
from rehab_hil.service.run_dir import METADATA_FILE, read_metadata

__all__ = ["angle_columns", "run_figures"]


def angle_columns(names: Any) -> tuple[str, str]:
    """(angle, reference) column names of a rig recording: ``<joint>_deg`` and ``<joint>_reference_deg``."""
    ref = next((n for n in names if n.endswith("_reference_deg")), None)
    if ref is None or ref.removesuffix("_reference_deg") + "_deg" not in names:
        raise ValueError("no angle and reference columns (<joint>_deg, <joint>_reference_deg): not a rig recording?")
    return ref.removesuffix("_reference_deg") + "_deg", ref


def run_figures(path: str | Path) -> dict[str, Any]:
    """``{"tracking": ..., "step_response": ...}`` of a run directory (or its run.csv / run.mcap);
    the step response only for a step run (its metadata's ``reference``), else None."""
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
    return {"tracking": metrics.recorded_tracking(rec[ref], rec[angle]), "step_response": step}
