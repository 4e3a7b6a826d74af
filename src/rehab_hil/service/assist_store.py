"""The assistance an assist-as-needed session learned, kept for the patient's next session.

``controllers/assist_as_needed.py`` learns the assistance of each direction across cycles; a
therapist expects the next session with the same patient on the same rig and config to start
where the last one ended, not from full assistance again. ``AssistanceStore`` keeps one small JSON
file per rig id, patient and config, ``<dir>/<rig>/<patient>-<config>.json``:

- ``<dir>``: the ``assistance_store`` option (``rehab-hil run --assistance-store DIR``), else
  ``REHAB_HIL_ASSISTANCE_DIR``, else ``$XDG_DATA_HOME/rehab-hil/assistance`` (``~/.local/share``):
  patient data, not a cache;
- ``<rig>`` and ``<patient>``: the session's identity (``service.identity.SessionIdentity``: the rig id,
  a simulated rig's ``--sim-plant`` part of it; the profile's ``patient_id`` and a simulated patient,
  both when both are given, else ``no-patient``), each through ``store_name``, as the rig learning's store.

The file holds the assistance per learned direction and what gives it meaning (``key``: the plant,
the controller, the directions it learns, the feedback's gains): one made under another key is not
used. Written atomically at the end of every session, a trip or a Ctrl-C included (what was learned
so far): a killed session leaves the previous file whole. A file that cannot be read or does not
match gives one line naming the file and what is wrong, and the session starts from the config's
``initial_assistance``.
"""

from __future__ import annotations

import datetime as dt
import json
import math
import os
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from rehab_hil.outputs import name_part, replacing
from rehab_hil.service.identity import store_name

__all__ = ["FORMAT", "AssistanceStore", "Stored", "default_assistance_dir"]

FORMAT = "rehab-hil assistance 1"


def default_assistance_dir() -> Path:
    """``REHAB_HIL_ASSISTANCE_DIR``, else ``$XDG_DATA_HOME/rehab-hil/assistance`` (``~/.local/share``)."""
    env = os.environ.get("REHAB_HIL_ASSISTANCE_DIR")
    if env:
        return Path(env)
    data = os.environ.get("XDG_DATA_HOME") or str(Path.home() / ".local" / "share")
    return Path(data) / "rehab-hil" / "assistance"



@dataclass(frozen=True)
class Stored:
    """What a store file holds: the assistance per direction, the sessions and moves it took."""

    assistance: dict[str, float]
    sessions: int
    saved_utc: str


class AssistanceStore:
    """One patient's learned assistance on one rig and config; see the module docstring."""

    def __init__(self, directory: Path, rig: str, patient: str | None, config_name: str,
                 key: dict[str, Any]) -> None:
        self.key = key
        self.path = Path(directory) / store_name(rig) / f"{store_name(patient)}-{name_part(config_name)}.json"

    def load(self) -> tuple[Stored | None, str | None]:
        """(what the file holds, None); (None, None) without a file; (None, one line) for a file that
        cannot be used: it names the file and what is wrong."""
        if not self.path.exists():
            return None, None
        try:
            data = json.loads(self.path.read_text(encoding="utf-8"))
        except (OSError, UnicodeDecodeError, json.JSONDecodeError) as e:
            return None, self._problem(f"unreadable ({type(e).__name__}: {e})")
        if not isinstance(data, dict) or data.get("format") != FORMAT:
            got = data.get("format") if isinstance(data, dict) else type(data).__name__
            return None, self._problem(f"not an assistance store (format {got!r}, expected {FORMAT!r})")
        stored_key = data.get("key")
        if stored_key != self.key:
            return None, self._problem(_key_difference(stored_key, self.key))
        assistance = data.get("assistance")
        if not isinstance(assistance, dict) or set(assistance) != set(self.key.get("directions", ())):
            return None, self._problem(f"'assistance' must hold {list(self.key.get('directions', ()))}")
        for k, v in assistance.items():
            if not isinstance(v, int | float) or isinstance(v, bool) or not 0.0 <= v <= 1.0 or math.isnan(v):
                return None, self._problem(f"'assistance.{k}' must be a number in 0..1, got {v!r}")
        sessions = data.get("sessions", 0)
        if not isinstance(sessions, int) or sessions < 0:
            return None, self._problem(f"'sessions' must be a whole number >= 0, got {sessions!r}")
        return Stored({k: float(v) for k, v in assistance.items()}, sessions, str(data.get("saved_utc", ""))), None

    def _problem(self, what: str) -> str:
        return f"assistance store {self.path}: {what}; starting from the config's initial assistance"

    def save(self, assistance: dict[str, float], sessions: int, ended: str) -> None:
        """Write the file atomically (a temporary file beside it, flushed, then renamed)."""
        self.path.parent.mkdir(parents=True, exist_ok=True)
        data = {"format": FORMAT, "key": self.key, "assistance": assistance, "sessions": sessions, "ended": ended,
                "saved_utc": dt.datetime.now(dt.UTC).isoformat(timespec="seconds")}
        with replacing(self.path) as tmp, open(tmp, "w", encoding="utf-8") as f:
            f.write(json.dumps(data, indent=1) + "\n")
            f.flush()
            os.fsync(f.fileno())


def _key_difference(stored: Any, wanted: dict[str, Any]) -> str:
    """What makes a stored key another session's (the first key that differs)."""
    if not isinstance(stored, dict):
        return "no 'key' table (what the assistance was learned for)"
    for k, v in wanted.items():
        if stored.get(k) != v:
            return f"learned for {k} {stored.get(k)!r}, this session has {v!r}"
    extra = sorted(set(stored) - set(wanted))
    return f"learned under other keys ({', '.join(extra)})"


class KeptAssistance:
    """One session's use of its store: the start it took (a stored assistance, unless ``fresh``)
    and, at ``finish``, what it learned, saved. ``directions``: {"open": "assistance.assist_open", ...}
    (``controllers.assist_as_needed.learned_directions``)."""

    def __init__(self, store: AssistanceStore, runtime: Any, directions: dict[str, str], fresh: bool) -> None:
        self.store, self.runtime, self.directions, self.fresh = store, runtime, directions, fresh
        stored, self.problem = (None, None) if fresh else store.load()
        self.resumed = stored is not None
        self.sessions_before = stored.sessions if stored is not None else 0
        if stored is not None:
            runtime.start_from({directions[d]: v for d, v in stored.assistance.items()})
        self.start = self._now()
        self.summary: dict[str, Any] | None = None

    def _now(self) -> dict[str, float]:
        states = self.runtime.discrete_states(tuple(self.directions.values()))
        return {d: states[q] for d, q in self.directions.items()}

    def finish(self, ended: str) -> dict[str, Any]:
        """Save what the session learned (once; later calls return the same summary): the store's
        path, where the session started from and what it saved (``error``: why it could not)."""
        if self.summary is not None:
            return self.summary
        end = self._now()
        error = None
        try:
            self.store.save(end, self.sessions_before + 1, ended)
        except OSError as e:
            error = f"assistance store {self.store.path}: not saved: {type(e).__name__}: {e}"
        self.summary = {"store": str(self.store.path), "resumed": self.resumed, "fresh": self.fresh,
                        "problem": self.problem, "start": self.start, "end": end,
                        "sessions": self.sessions_before + 1, "ended": ended, "error": error}
        return self.summary
