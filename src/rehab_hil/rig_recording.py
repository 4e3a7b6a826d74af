"""A rig recording as the model sees it: a run directory, its CSV or its MCAP, on a plant's signals.

The recorder names columns after the rig binding's state and command interfaces, which are the
model's signal names (``iris_angle_deg``, ``patient_torque_nm``, ``pwm_duty`` ...), so the only
mapping left is for model inputs a rig never records: the constants the plant's ports take from
the config (the SMA supply voltage). Those are filled in, and said so. The interchange CSV written
by ``simulate`` is read the same way.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from rehab_hil.interchange import CsvError, Recording, may_be_empty, read_csv
from rehab_hil.loop.run_dir import METADATA_FILE, read_metadata

__all__ = ["LoadedRecording", "load_recording", "read_mcap_recording", "read_recording"]

MCAP_MAGIC = b"\x89MCAP0\r\n"


@dataclass
class LoadedRecording:
    """The recording on the model's signals, the file it came from, and what was done to it."""

    recording: Recording
    source: Path
    notes: list[str] = field(default_factory=list)  # warnings for the user: truncation, filled inputs
    metadata: dict[str, Any] | None = None


def read_mcap_recording(path: str | Path) -> tuple[Recording, bool]:
    """The ``/rig/sample`` messages of a session MCAP as columns, and whether the file was cut short
    (no footer: a killed run; everything up to the last complete message is kept). A column with a
    null is left out, except a reference column: NaN where no reference was tracked, as in run.csv."""
    from rehab_hil.loop.recorder import read_mcap

    path = Path(path)
    try:
        with path.open("rb") as fh:
            head = fh.read(len(MCAP_MAGIC))
            fh.seek(max(0, path.stat().st_size - len(MCAP_MAGIC)))
            tail = fh.read()
    except OSError as e:
        raise CsvError(path, None, f"cannot open: {e.strerror}") from None
    if head != MCAP_MAGIC:
        raise CsvError(path, None, "not an MCAP file (bad magic)")
    rows = [msg for topic, _, msg in read_mcap(path) if topic == "/rig/sample"]
    if not rows:
        raise CsvError(path, None, "no /rig/sample messages: the run recorded no sample")
    names = [k for k, v in rows[0].items() if k != "time_s" and (isinstance(v, int | float) or v is None)]
    t = np.array([r["time_s"] for r in rows], float)
    keep = np.concatenate([[True], np.diff(t) > 0])  # strictly increasing time, as the CSV
    signals = {k: np.array([np.nan if r.get(k) is None else r[k] for r in rows], float)[keep] for k in names}
    kept = {k: v for k, v in signals.items() if np.all(np.isfinite(v)) or may_be_empty(k)}
    return Recording(t[keep], kept), tail != MCAP_MAGIC


def _run_files(run_dir: Path) -> tuple[Path | None, Path | None]:
    csv, mcap = run_dir / "run.csv", run_dir / "run.mcap"
    return (csv if csv.is_file() else None), (mcap if mcap.is_file() else None)


def read_recording(path: str | Path) -> LoadedRecording:
    """Read ``path``: a run directory (its ``run.csv``, else its ``run.mcap``), a ``.mcap`` or a CSV.

    Errors (``CsvError``) name the file: an empty or foreign directory, an unreadable file. A cut-short
    CSV or MCAP is read up to its last complete sample, with a note."""
    path = Path(path)
    notes: list[str] = []
    metadata = None
    if path.is_dir():
        csv, mcap = _run_files(path)
        if csv is None and mcap is None:
            raise CsvError(path, None, "no run.csv or run.mcap here: an empty or unfinished run directory")
        if (path / METADATA_FILE).is_file():
            try:
                metadata = read_metadata(path)
            except ValueError as e:
                notes.append(str(e))
        path = csv or mcap  # type: ignore[assignment]
    elif not path.exists():
        raise CsvError(path, None, "no such file or directory")
    if path.suffix == ".mcap":
        rec, cut = read_mcap_recording(path)
        if cut:
            notes.append(f"{path}: no MCAP footer (the run was killed?): analysed up to its last complete sample "
                         f"(t = {rec.t[-1]:.3f} s)")
    else:
        rec = read_csv(path, drop_partial_tail=True)
        if rec.truncated:
            notes.append(f"{path}: the last line was cut short (the run was killed?): analysed up to the last "
                         f"complete sample (t = {rec.t[-1]:.3f} s)")
    rec.rig = metadata is not None or "raw_adc0_counts" in rec.signals  # the recorder's raw columns
    return LoadedRecording(rec, path, notes, metadata)


def _needs_mapping(path: Path, have_mapping: bool) -> bool:
    """A ``.mat`` file always goes through ``[import]``; a CSV does when the config has one and the
    file is not an interchange CSV (its first header cell is not ``time_s``: a logger's own columns)."""
    if path.suffix.lower() == ".mat":
        return True
    if not have_mapping or not path.is_file() or path.suffix.lower() not in (".csv", ".txt", ".tsv", ".dat"):
        return False  # a run directory or its MCAP is the recorder's own
    try:
        with path.open("rb") as fh:
            first = fh.readline(4096).decode("utf-8", "replace")
    except OSError:
        return False  # the reader names the unreadable file
    return first.split(",")[0].strip().strip('"') != "time_s"


def load_recording(path: str | Path, plant: Any, cfg: Any) -> LoadedRecording:
    """``read_recording`` for ``plant`` under ``cfg``: a run of another plant (its metadata says) is
    refused, and model inputs a rig does not record are filled from the config's constants."""
    mapping = getattr(cfg, "import_", None)
    if _needs_mapping(Path(path), mapping is not None):  # a lab logger's file: the config's [import] reads it
        from rehab_hil.importing import read_mapped

        if mapping is None:
            raise CsvError(path, None, "a .mat file needs an [import] table in the plant config (which variable is "
                                       "which signal), or convert it first with `rehab-hil import --mapping`")
        loaded = LoadedRecording(read_mapped(path, mapping, "[import] of the config"), Path(path), [], None)
    else:
        loaded = read_recording(path)
    meta, rec = loaded.metadata, loaded.recording
    if meta and meta.get("plant") not in (None, plant.name):
        raise CsvError(loaded.source.parent / METADATA_FILE, None,
                       f"a {meta['plant']!r} recording; the config is a {plant.name!r} plant")
    for name, value in plant.ports(cfg).constants.items():
        if name in plant.inputs and name not in rec.signals and name not in plant.optional_inputs:
            rec.signals[name] = np.full(rec.t.size, float(value))
            loaded.notes.append(f"{name} is not recorded: taken from the config ({value:g})")
    return loaded
