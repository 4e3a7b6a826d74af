"""What ``rehab-hil monitor`` (no rig id) shows: one compact row per live rig of the lab.

Three wildcard subscriptions (``rehab/*/state``, ``rehab/*/stats``, ``rehab/*/safety``) and the
liveliness watch feed a thread-safe model; only the last record of each state batch is kept, so
the cost per rig stays one decode per batch. ``render`` draws the table with rich.
"""

from __future__ import annotations

import contextlib
import math
import threading
import time
from dataclasses import dataclass, field
from typing import Any

import zenoh
from rich.table import Table

from rehab_hil.telemetry.codec import PayloadError, StateSample, decode_json, decode_state
from rehab_hil.telemetry.keys import PREFIX, rig_from_key

__all__ = ["LabView", "RigRow", "render_lab"]


@dataclass
class RigRow:
    """The latest of one rig: sample, record count for the rate, stats, safety, liveliness, plant."""

    rig: str
    alive: bool = True
    plant: str = "-"
    latest: StateSample | None = None
    latest_state: StateSample | None = None  # the last record with an estimate (a command record has none)
    records: int = 0
    lost_batches: int = 0
    publisher_dropped: int = 0
    next_batch: int | None = None
    stats: dict[str, Any] = field(default_factory=dict)
    safety: str = ""
    marks: list[tuple[float, int]] = field(default_factory=list)

    def rate_hz(self, now: float) -> float:
        recent = [m for m in self.marks if m[0] >= now - 3.0]
        if len(recent) < 2 or recent[-1][0] <= recent[0][0]:
            return math.nan
        return (recent[-1][1] - recent[0][1]) / (recent[-1][0] - recent[0][0])


class LabView:
    """Live rows of every rig on the session's router; ``close()`` undeclares everything."""

    def __init__(self, session: zenoh.Session, clock: Any = time.monotonic) -> None:
        self._clock = clock
        self._lock = threading.Lock()
        self.rows: dict[str, RigRow] = {}
        self._subs: list[Any] = []
        try:
            self._subs.append(session.declare_subscriber(f"{PREFIX}/*/state", self._state))
            self._subs.append(session.declare_subscriber(f"{PREFIX}/*/stats", self._json("stats")))
            self._subs.append(session.declare_subscriber(f"{PREFIX}/*/safety", self._json("safety")))
            self._subs.append(session.liveliness().declare_subscriber(f"{PREFIX}/*/alive", self._alive,
                                                                      history=True))
        except Exception:
            self.close()
            raise

    def _row(self, key: Any) -> RigRow | None:
        try:
            rig = rig_from_key(str(key))
        except ValueError:
            return None
        row = self.rows.get(rig)
        if row is None:
            row = self.rows[rig] = RigRow(rig)
        return row

    def _alive(self, s: zenoh.Sample) -> None:
        with self._lock:
            row = self._row(s.key_expr)
            if row is not None:
                row.alive = s.kind == zenoh.SampleKind.PUT

    def _state(self, s: zenoh.Sample) -> None:
        try:
            batch = decode_state(s.payload.to_bytes())
        except PayloadError:
            return
        with self._lock:
            row = self._row(s.key_expr)
            if row is None or not batch.samples:
                return
            if row.next_batch is not None and batch.batch_seq != row.next_batch:
                row.lost_batches += (batch.batch_seq - row.next_batch) & 0xFFFFFFFF
            row.next_batch = (batch.batch_seq + 1) & 0xFFFFFFFF
            row.records += len(batch.samples)
            row.publisher_dropped = batch.dropped_total
            row.latest = batch.samples[-1]
            row.latest_state = next((x for x in reversed(batch.samples) if x.has_state), row.latest_state)
            row.marks.append((self._clock(), row.records))
            del row.marks[:-64]

    def _json(self, kind: str) -> Any:
        def handle(s: zenoh.Sample) -> None:
            try:
                msg = decode_json(s.payload.to_bytes(), expect=kind)
            except PayloadError:
                return
            with self._lock:
                row = self._row(s.key_expr)
                if row is None:
                    return
                if kind == "stats":
                    row.stats = msg
                else:
                    row.safety = f"{msg.get('reason', msg.get('state', '?'))} {msg.get('detail', '')}".strip()

        return handle

    def set_plant(self, rig: str, plant: str | None) -> None:
        with self._lock:
            row = self.rows.setdefault(rig, RigRow(rig))
            row.plant = plant or "-"

    def live(self) -> list[str]:
        """Rig ids whose liveliness token is present now, sorted."""
        with self._lock:
            return sorted(r.rig for r in self.rows.values() if r.alive)

    def snapshot(self) -> list[RigRow]:
        with self._lock:
            return [RigRow(**{**vars(r), "marks": list(r.marks), "stats": dict(r.stats)})
                    for _, r in sorted(self.rows.items())]

    def close(self) -> None:
        for s in self._subs:
            with contextlib.suppress(zenoh.ZError):
                s.undeclare()
        self._subs.clear()


def _f(v: float, digits: int = 1) -> str:
    return f"{v:.{digits}f}" if isinstance(v, (int, float)) and math.isfinite(v) else "-"


def render_lab(rows: list[RigRow], now: float | None = None) -> Table:
    """One line per rig: state, plant, rate, angle/reference, first analog, duty, temperature, safety, losses."""
    now = time.monotonic() if now is None else now
    t = Table(title=f"rehab lab: {sum(r.alive for r in rows)} live rig(s); lost = batches in transit / "
              "samples dropped at the rig's publisher", box=None, header_style="bold")
    for col in ("rig", "state", "plant", "rec/s", "angle deg", "ref deg", "analog0", "duty", "temp C", "safety",
                "lost"):
        t.add_column(col, justify="left" if col in ("rig", "state", "plant", "safety") else "right")
    if not rows:
        t.add_row("(no rig)", *[""] * 10)
    for r in rows:
        s, st = r.latest, r.latest_state  # the angle and analog values: from the last record that has them
        state = "[green]live" if r.alive else "[red]gone"
        safety = r.safety or (s.safety if s is not None and s.safety not in ("unknown",) else ("ok" if s else "-"))
        t.add_row(r.rig, state, r.plant, _f(r.rate_hz(now), 0),
                  _f(st.angle_deg if st else math.nan), _f(s.reference_deg if s else math.nan),
                  _f(st.analog[0] if st and st.analog else math.nan, 3), _f(s.command_duty0 if s else math.nan, 3),
                  _f(s.temperature_c if s else math.nan), safety,
                  f"{r.lost_batches}b/{r.publisher_dropped}" if s else "-")
    return t
