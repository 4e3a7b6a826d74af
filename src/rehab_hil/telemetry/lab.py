"""A lab of rigs on one zenoh router: rig patterns, rig discovery, recording several rigs at once.

``LabRecorder`` records every live rig whose id matches a pattern (and those that appear later),
each into its own run directory (``loop.run_dir.new_run_dir``: run.csv, run.mcap, metadata.json).
Zenoh callbacks only note which rigs came and went; info queries and file creation happen on the
caller's thread (``poll``), never inside a zenoh callback. docs/telemetry.md, "A lab of rigs".
"""

from __future__ import annotations

import datetime as dt
import fnmatch
import hashlib
import re
import tempfile
import threading
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import zenoh

from rehab_hil.interfaces import DeviceBinding
from rehab_hil.loading import load_config
from rehab_hil.loop.run_dir import new_run_dir, write_metadata
from rehab_hil.plants import get_plant
from rehab_hil.telemetry.subscriber import query_info, watch_alive
from rehab_hil.telemetry.zrecord import ZenohRecorder

__all__ = ["LabError", "LabRecorder", "RigWatch", "binding_from_info", "rig_matcher"]

_PATTERN = re.compile(r"^[A-Za-z0-9_.\-*?\[\]!]{1,63}$")


class LabError(ValueError):
    """A lab request that cannot be met (bad pattern, rig without config); the message is one line."""


def rig_matcher(pattern: str) -> Callable[[str], bool]:
    """A predicate on rig ids for a shell-style ``pattern`` (``*``, ``?``, ``[...]``), e.g. ``bench*``."""
    if not isinstance(pattern, str) or not _PATTERN.match(pattern):
        raise LabError(f"rig pattern {pattern!r} must be 1-63 characters of letters, digits, '_', '-', '.' and the "
                       "wildcards '*', '?', '[...]'")
    return lambda rig: fnmatch.fnmatchcase(rig, pattern)


def binding_from_info(info: dict[str, Any] | None, rig: str, config: Path | None = None) -> DeviceBinding:
    """The plant's device binding from ``config``, else from the config text the rig reports in ``info``."""
    if config is not None:
        cfg = load_config(config)
    else:
        text = (info or {}).get("config_toml")
        if not text:
            raise LabError(f"rig {rig!r} did not report its config; pass --config")
        with tempfile.TemporaryDirectory() as d:
            path = Path(d) / "rig_config.toml"
            path.write_text(text, encoding="utf-8")
            cfg = load_config(path)
    spec = get_plant(cfg.plant)
    if spec.device is None:
        raise LabError(f"plant {spec.name!r} has no device binding")
    return spec.device(cfg)


class RigWatch:
    """Which rigs are live (liveliness tokens), and which came or went since the last ``changes()``."""

    def __init__(self, session: zenoh.Session, matches: Callable[[str], bool] = lambda rig: True) -> None:
        self.matches = matches
        self.alive: set[str] = set()
        self._changes: list[tuple[str, bool]] = []
        self._lock = threading.Lock()
        self._sub = watch_alive(session, self._on_change)

    def _on_change(self, rig: str, alive: bool) -> None:
        if not self.matches(rig):
            return
        with self._lock:
            (self.alive.add if alive else self.alive.discard)(rig)
            self._changes.append((rig, alive))

    def changes(self) -> list[tuple[str, bool]]:
        """(rig, alive) events since the previous call, oldest first."""
        with self._lock:
            out, self._changes = self._changes, []
        return out

    def live(self) -> list[str]:
        with self._lock:
            return sorted(self.alive)

    def close(self) -> None:
        self._sub.undeclare()


def _identity(rig: str, info: dict[str, Any], started: dt.datetime) -> dict[str, Any]:
    """What a zenoh recording knows of its rig: the ``info`` answer (plant, config, versions)."""
    text = info.get("config_toml") or ""
    return {
        "rig_id": rig, "source": "zenoh", "recorded_by": "rehab-hil record --from-zenoh",
        "plant": info.get("plant"), "config_path": info.get("config_path"),
        "config_sha256": hashlib.sha256(text.encode()).hexdigest() if text else None, "config_text": text or None,
        "firmware_version": info.get("firmware_version"),
        "device_protocol_version": info.get("device_protocol_version"),
        "host_protocol_version": info.get("host_protocol_version"), "period_s": info.get("period_s"),
        "start_utc": started.isoformat(),
    }


class _Run:
    def __init__(self, rig: str, run_dir: Path, zrec: ZenohRecorder, meta: dict[str, Any]) -> None:
        self.rig, self.run_dir, self.zrec, self.meta = rig, run_dir, zrec, meta
        self.t0 = time.monotonic()


def _said(acc: dict[str, Any]) -> str:
    """The recording's losses in one phrase: how many of the rig's samples it lacks and where they went."""
    missing, lost = acc["samples_not_received"], acc["lost"]
    if missing is None:
        return (f"{acc['samples_received']} samples received; the rig's final count did not arrive: samples "
                "after the last one received unknown")
    lacks = missing + lost["in_writer"]
    where = ", ".join(f"{lost[k] if lost[k] is not None else '?'} {what}" for k, what in (
        ("at_publisher", "dropped at the rig's publisher"),
        ("before_joining", "from before it joined, not in the publisher's history"),
        ("in_transit", "lost in transit"), ("in_writer", "refused by the writer")))
    extra = f", {lost['unexplained']} unexplained" if lost["unexplained"] else ""
    got = f"{acc['samples_received']} of the rig's {acc['rig_samples']} samples received"
    return f"{got}, {lacks} missing: {where}{extra}"


class LabRecorder:
    """Record every rig matching ``pattern`` under ``out_root``, one run directory per rig."""

    def __init__(self, session: zenoh.Session, pattern: str, out_root: str | Path, config: Path | None = None,
                 info_timeout_s: float = 2.0, final_timeout_s: float = 10.0, history: bool = True,
                 recovery: bool = False) -> None:
        self.session, self.pattern, self.out_root, self.config = session, pattern, Path(out_root), config
        self.info_timeout_s = info_timeout_s
        self.history, self.recovery = history, recovery  # zenoh's AdvancedSubscriber (subscriber.py)
        self.final_timeout_s = final_timeout_s  # how long a stopped rig's last batches may take to arrive
        self.runs: dict[str, _Run] = {}
        self.finished: list[_Run] = []
        self.errors: list[str] = []
        self.watch = RigWatch(session, rig_matcher(pattern))

    def poll(self) -> list[str]:
        """Start recorders for rigs that appeared and finish those whose rig went; returns what happened."""
        said: list[str] = []
        for rig, alive in self.watch.changes():
            if alive and rig not in self.runs:
                try:
                    run = self._start(rig)
                except (LabError, ValueError) as e:
                    self.errors.append(f"rig {rig}: {e}")
                    said.append(f"rig {rig}: not recorded: {e}")
                    continue
                said.append(f"recording rig {rig} into {run.run_dir}")
            elif not alive and rig in self.runs:
                said.append(self._finish(rig, "rig stopped"))
        return said

    def _start(self, rig: str) -> _Run:
        info = query_info(self.session, rig, timeout_s=self.info_timeout_s)
        if info is None and self.config is None:
            raise LabError(f"did not answer on rehab/{rig}/info within {self.info_timeout_s} s")
        binding = binding_from_info(info, rig, self.config)
        run_dir = new_run_dir(self.out_root, rig)
        meta = _identity(rig, dict(info or {}), dt.datetime.now(dt.UTC))
        period = (info or {}).get("period_s")
        zrec = ZenohRecorder(self.session, rig, run_dir, binding, metadata=meta,
                             period_s=float(period) if isinstance(period, (int, float)) else None,
                             history=self.history, recovery=self.recovery)
        run = _Run(rig, run_dir, zrec, meta)
        self.runs[rig] = run
        return run

    def _finish(self, rig: str, why: str) -> str:
        run = self.runs.pop(rig)
        z, sub = run.zrec, run.zrec.subscription
        # the last batches and the rig's final word travel behind the liveliness change; a rig that
        # is still running (--duration reached) or was killed sends none: its tail is then unknown
        z.wait_finished(self.final_timeout_s if z.done.is_set() else 0.0)
        sub.close()  # counters final from here on
        acc = z.accounting()
        summary = {"duration_s": round(time.monotonic() - run.t0, 3), "stop_reason": why, "records": z.samples,
                   "samples": acc, "lost": acc["lost"]}
        z.close(summary)  # also the MCAP metadata record rehab_hil.summary
        self.finished.append(run)
        write_metadata(run.run_dir, {**run.meta, **summary, "csv_rows": z.recorder.rows})
        return (f"{why}: rig {rig}: {z.samples} records, {z.recorder.rows} CSV rows in {run.run_dir}; "
                f"{_said(acc)}; {acc['sample_index_gaps']} gaps in sample_index")

    def close(self, why: str = "duration reached") -> list[str]:
        """Finish every running recording; returns one line per rig."""
        said = [self._finish(rig, why) for rig in sorted(self.runs)]
        self.watch.close()
        return said
