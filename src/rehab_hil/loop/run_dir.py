"""Run directories: every recorded session gets a new one, never overwriting an earlier run.

``<root>/<UTC start, YYYYmmddTHHMMSSZ>-<rig id>/`` holds ``run.csv``, ``run.mcap`` and
``metadata.json``: what a recording needs to be traced back to the model, firmware and rig it
ran against (plant, config path, hash and full text, firmware and protocol versions, device,
calibration, start time, duration, summary figures, safety events, the sinks' drops and errors).
"""

from __future__ import annotations

import datetime as dt
import hashlib
import json
import os
import platform
import re
import sys
from importlib import metadata as importlib_metadata
from pathlib import Path
from typing import Any

from rehab_hil.outputs import name_part

__all__ = ["METADATA_FILE", "METADATA_SCHEMA", "RUN_FILES", "config_identity", "is_run_dir", "new_run_dir",
           "read_metadata", "reference_metadata", "result_metadata", "session_metadata", "write_metadata"]

METADATA_FILE = "metadata.json"
METADATA_SCHEMA = "rehab-hil/run-metadata/1"
RUN_FILES = ("run.csv", "run.mcap")
RUN_NAME = re.compile(r"^\d{8}T\d{6}Z-")  # new_run_dir's names: the UTC start time first



def is_run_dir(path: str | Path) -> bool:
    """A run directory of ``run --record``: it holds ``metadata.json``, or (a run killed before its
    metadata) is named like one and holds run.csv or run.mcap. The ``--record`` folder itself is
    not, even beside a ``simulate --out out/run.csv``."""
    p = Path(path)
    if not p.is_dir():
        return False
    return (p / METADATA_FILE).is_file() or (RUN_NAME.match(p.name) is not None
                                             and any((p / f).is_file() for f in RUN_FILES))


def new_run_dir(root: str | Path, rig_id: str, now: dt.datetime | None = None) -> Path:
    """Create and return a fresh run directory under ``root`` (``-2``, ``-3`` ... on a clash)."""
    root = Path(root)
    root.mkdir(parents=True, exist_ok=True)
    stamp = (now or dt.datetime.now(dt.UTC)).strftime("%Y%m%dT%H%M%SZ")
    base = f"{stamp}-{name_part(rig_id, 'rig')}"
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


def _version() -> str:
    try:
        return importlib_metadata.version("rehab-hil")
    except importlib_metadata.PackageNotFoundError:
        return "unknown"


def session_metadata(*, plant: str, config_path: str | Path, device: str, rig_id: str, binding: Any,
                     hello: Any | None, controller: str, pacing: str, sim_plant: str | Path | None = None,
                     calibration: dict[str, Any] | None = None,
                     reference: dict[str, Any] | None = None) -> dict[str, Any]:
    """What is known when a run starts: the model, the device and its firmware, the calibration."""
    fw = None
    if hello is not None:
        fw = {"name": "rehab_fw", "version": f"{hello.fw_major}.{hello.fw_minor}.{hello.fw_patch}",
              "protocol_version": hello.protocol_version, "n_pwm": hello.n_pwm, "n_adc": hello.n_adc,
              "encoder_counts_per_rev": hello.encoder_counts_per_rev, "reset_cause": hello.reset_cause}
    simulated = device in ("sim", "avr", "inprocess")
    return {
        "plant": plant, **config_identity(config_path),
        "sim_plant": config_identity(sim_plant) if sim_plant else None,
        "device": {"kind": device if simulated else "serial", "port": None if simulated else device},
        "firmware": fw, "rig_id": rig_id, "controller": controller, "pacing": pacing, "reference": reference,
        "calibration": {
            "encoder_counts_per_rev": binding.encoder_counts_per_rev,
            "adc": [{"signal": ch.signal, "source": f"adc{i}", "kind": ch.kind, "unit": ch.unit,
                     "counts_per_unit": ch.counts_per_unit, "offset_counts": ch.offset_counts}
                    for i, ch in enumerate(binding.adc)],
            **(calibration or {}),
        },
        "start_time_utc": dt.datetime.now(dt.UTC).isoformat(timespec="milliseconds"),
        "host": platform.node(), "rehab_hil_version": _version(), "command": sys.argv,
    }


def reference_metadata(reference: Any) -> dict[str, Any] | None:
    """What the controller tracked (``controllers.Reference``): its kind and values [deg, s]; None
    for a controller without one."""
    if reference is None:
        return None
    keys = (("start_deg", "open_deg") if reference.kind == "step" else
            ("closed_deg", "open_deg", "move_s", "hold_open_s", "hold_closed_s", "first_open_s", "period_s"))
    return {"kind": reference.kind, **{k: float(getattr(reference, k)) for k in keys}}


def result_metadata(result: Any, rows: int) -> dict[str, Any]:
    """What is known when it ends: the time it ran (``duration_s``; ``requested_duration_s`` what was
    asked), summary figures, a step run's response, the safety events and the sinks' drops and errors."""
    ran = getattr(result, "ran_s", None)
    return {
        "end_time_utc": dt.datetime.now(dt.UTC).isoformat(timespec="milliseconds"),
        "duration_s": ran if isinstance(ran, int | float) and ran == ran else result.duration_s,
        "requested_duration_s": result.duration_s, "stop_reason": result.stop_reason, "rows": rows,
        "step_response": getattr(result, "step", None) or None,
        "cycles": result.cycles, "samples": result.samples, "sample_gaps": result.sample_gaps,
        "reboots": result.reboots, "tracking": result.tracking, "timing": result.timing, "link": result.link,
        "safety_events": [{"t_s": e.t_s, "reason": e.reason, "detail": e.detail, "cause": e.cause}
                          for e in result.events],
        "pwm_off_at_end": result.pwm_off_at_end,  # None: unconfirmed (why: pwm_unconfirmed)
        "pwm_unconfirmed": result.pwm_unconfirmed, "stalls": result.stalls,
        "sinks": result.sinks,  # each sink's drops and error (None, or the one line it failed with)
        "session": result.session, "session_cycles": result.session_cycles,
        "rig_learning": getattr(result, "learning", None) or None,
        "assistance_store": getattr(result, "assistance", None) or None,
    }
