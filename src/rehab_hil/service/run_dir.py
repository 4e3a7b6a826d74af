"""Run directories: every recorded session gets a new one, never overwriting an earlier run.

``<root>/<UTC start, YYYYmmddTHHMMSSZ>-<rig id>/`` holds ``run.csv``, ``run.mcap`` and
``metadata.json``: what a recording needs to be traced back to the model, firmware and rig it
ran against (plant, config path, hash and full text, firmware and protocol versions, device,
calibration, start time, duration, summary figures, safety events).
"""

from __future__ import annotations

import datetime as dt
import hashlib
import json
import os
import re
from pathlib import Path
from typing import Any

__all__ = ["METADATA_FILE", "METADATA_SCHEMA", "config_identity", "new_run_dir", "read_metadata",
           "write_metadata"]

METADATA_FILE = "metadata.json"
METADATA_SCHEMA = "rehab-hil/run-metadata/1"


def _slug(text: str) -> str:
    return re.sub(r"[^A-Za-z0-9_.-]+", "-", text).strip("-") or "rig"


def new_run_dir(root: str | Path, rig_id: str, now: dt.datetime | None = None) -> Path:
    """Create and return a fresh run directory under ``root`` (``-2``, ``-3`` ... on a clash)."""
    root = Path(root)
    root.mkdir(parents=True, exist_ok=True)
    stamp = (now or dt.datetime.now(dt.UTC)).strftime("%Y%m%dT%H%M%SZ")
    base = f"{stamp}-{_slug(rig_id)}"
    for i in range(1, 10_000):
        path = root / (base if i == 1 else f"{base}-{i}")
        try:
            path.mkdir()
        except FileExistsError:
            continue
        return path
    raise FileExistsError(f"{root}: no free run directory name for {base}")


def config_identity(path: str | Path) -> dict[str, str]:
    """The config a run used: its path, sha256 and full text (the file may change later)."""
    p = Path(path)
    text = p.read_text(encoding="utf-8")
    return {"config_path": str(p), "config_sha256": hashlib.sha256(text.encode()).hexdigest(), "config_text": text}


def write_metadata(run_dir: str | Path, meta: dict[str, Any]) -> Path:
    """Write ``metadata.json`` atomically (a killed run never leaves half a file)."""
    path = Path(run_dir) / METADATA_FILE
    tmp = path.with_suffix(f".{os.getpid()}.tmp")
    tmp.write_text(json.dumps({"schema": METADATA_SCHEMA, **meta}, indent=2, default=str) + "\n")
    os.replace(tmp, path)
    return path


def read_metadata(run_dir: str | Path) -> dict[str, Any]:
    """The run's metadata; a missing or unreadable file raises ValueError naming it."""
    path = Path(run_dir) / METADATA_FILE
    try:
        return json.loads(path.read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise ValueError(f"{path}: no metadata file (not a rehab-hil run directory?)") from None
    except (OSError, json.JSONDecodeError) as e:
        raise ValueError(f"{path}: unreadable metadata: {e}") from None
