"""What ``--data`` names, as a person types it: a run directory, its run.csv / run.mcap, an
interchange CSV, or the ``--record`` folder itself, whose newest run is taken (and said so) --
and the channels the analysis needs but the record lacks, named."""

from __future__ import annotations

import sys
from pathlib import Path
from typing import Any

from rehab_hil.loop.run_dir import is_run_dir

__all__ = ["load_checked", "missing_channels", "resolve_data"]

def resolve_data(path: Path, command: str, flag: str = "--data") -> Path:
    """``path``, or the newest run directory inside it when it is a folder of runs (run directories
    start with their UTC start time): that choice is printed to standard error. Only run directories
    count: a ``simulate --out`` CSV beside them in the folder is not taken for a run."""
    if not path.is_dir() or is_run_dir(path):
        return path
    runs = sorted(d for d in path.iterdir() if is_run_dir(d))
    files = sorted(f.name for f in path.iterdir() if f.suffix in (".csv", ".mcap", ".mat"))
    if not runs and not files:
        return path  # the reader names the empty folder
    if not runs:  # a simulate --out CSV is not a run: taking it silently analysed the wrong data
        from rehab_hil.cli import UserError

        raise UserError(f"{flag} {path}: no run directory here (`rehab-hil run --record DIR` writes "
                        f"DIR/<UTC time>-<rig id>/ with metadata.json); to use a file in it, name the file "
                        f"({', '.join(files[:3])})")
    newest = runs[-1]
    others = f"; the other {len(runs) - 1}: " + ", ".join(d.name for d in runs[-2::-1][:5]) + \
        (" ..." if len(runs) > 6 else "") if len(runs) > 1 else ""
    what = f"holds {len(runs)} runs: using the newest" if len(runs) > 1 else "holds one run: using it"
    print(f"rehab-hil {command}: {flag} {path} {what}, {newest}{others}", file=sys.stderr)
    return newest


def missing_channels(plant: Any, cfg: Any, signals: dict[str, Any]) -> list[str]:
    """The plant outputs a rig records (its encoder angle, its sensors) that ``signals`` lacks."""
    try:
        binding = plant.device(cfg)
    except Exception:  # a plant without a rig binding: every output is optional
        return []
    wanted = [binding.angle_output, *(ch.signal for ch in binding.adc)]
    return [c for c in dict.fromkeys(wanted) if c in plant.outputs and c not in signals]


def load_checked(path: Path, plant: Any, cfg: Any, command: str, without: str | None = None) -> Any:
    """A record read through ``rig_recording.load_recording`` (the config's ``[import]`` for a lab's
    file) and checked replayable; its notes, and with ``without`` (what happens then) each channel
    the rig records but the file lacks, as warnings on standard error. Returns the ``LoadedRecording``."""
    from rehab_hil.discrepancy.replay import check_recording
    from rehab_hil.rig_recording import load_recording

    loaded = load_recording(path, plant, cfg)
    for note in loaded.notes:
        print(f"rehab-hil {command}: warning: {note}", file=sys.stderr)
    for c in missing_channels(plant, cfg, loaded.recording.signals) if without else ():
        print(f"rehab-hil {command}: warning: {loaded.source}: no {c!r} column (a {plant.name} output the rig "
              f"records): {without}", file=sys.stderr)
    check_recording(plant, loaded.recording, loaded.source, cfg)
    return loaded
