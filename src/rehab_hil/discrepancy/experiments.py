"""What the records lack: the experiments that would tell direction- and speed-dependent effects apart.

From the measured position (or angle) of each record: does the axis move both ways over the
records (``both directions``), within one record (``a reversal``), at several speeds (the moving
speeds spread by more than ``SPEED_SPREAD`` of their median), and does it rest between moves (``a
hold``)? A suggestion names only what the records do not already hold (issue 38: "moves at several
constant speeds" was suggested when every record held that, "move in both directions" never).
"""

from __future__ import annotations

from typing import Any

import numpy as np

__all__ = ["EXPERIMENTS", "MOVING_SHARE", "SPEED_SPREAD", "coverage", "lacking", "mend_suggestions"]

MOVING_SHARE = 0.1  # moving: speed above this share of the record's 95th-percentile speed
SPEED_SPREAD = 0.3  # several speeds: (90th - 10th percentile) / median of the moving speeds
HOLD_SHARE = 0.05  # a hold: at least this share of the record at rest

EXPERIMENTS = {
    "both directions": "move in both directions (direction-dependent friction and loads show only then)",
    "a reversal": "a reversal within one record (friction's sign change, a play at the turn)",
    "several speeds": "moves at several constant speeds (Coulomb friction does not grow with speed, viscous does)",
    "a hold": "a hold at rest between moves (stiction and a constant load show at rest)",
}


def _positions(replay: Any) -> list[tuple[np.ndarray, np.ndarray]]:
    """(t, position) of every record whose replay measures an angle or a position."""
    reps = getattr(replay, "replays", [replay])
    out = []
    for r in reps:
        kinds = r.kinds
        ch = next((c for c in r.channels if kinds.get(c) in ("angle", "position")), None)
        if ch is not None:
            out.append((r.t, np.asarray(r.measured[ch], float)))
    return out


def coverage(replay: Any) -> dict[str, bool] | None:
    """Which of ``EXPERIMENTS`` the records hold (None: no position channel to tell)."""
    pos = _positions(replay)
    if not pos:
        return None
    signs: set[int] = set()
    reversal = hold = several = False
    for t, y in pos:
        n = max(1, round(0.02 / max(float(np.median(np.diff(t))), 1e-9)))  # 20 ms differences
        v = (y[n:] - y[:-n]) / (t[n:] - t[:-n])
        top = float(np.percentile(np.abs(v), 95)) if v.size else 0.0
        if top <= 0.0:
            continue
        moving = np.abs(v) > MOVING_SHARE * top
        s = set(np.sign(v[moving]).astype(int).tolist())
        signs |= s
        reversal |= len(s) > 1
        hold |= float(np.mean(~moving)) >= HOLD_SHARE
        sp = np.abs(v[moving])
        several |= sp.size > 0 and (np.percentile(sp, 90) - np.percentile(sp, 10)) > SPEED_SPREAD * np.median(sp)
    return {"both directions": len(signs) > 1, "a reversal": reversal, "several speeds": bool(several),
            "a hold": hold}


def lacking(replay: Any) -> list[str]:
    """The experiments (``EXPERIMENTS``' sentences) the records do not hold, for an axis plant."""
    cov = coverage(replay)
    if cov is None or "axis" not in replay.ports.kinds():
        return []
    return [EXPERIMENTS[k] for k, have in cov.items() if not have]


def mend_suggestions(aliases: list[Any], replay: Any) -> None:
    """An alias's suggested experiment that the records already hold ("moves at several constant
    speeds" on records that hold several speeds) is replaced by what they lack, or by a statement
    that they hold it and the two still act alike here."""
    cov = coverage(replay)
    if cov is None:
        return
    missing = [EXPERIMENTS[k] for k, have in cov.items() if not have]
    for a in aliases:
        held = [k for k, have in cov.items() if have and a.experiment.startswith(EXPERIMENTS[k].split(" (")[0])]
        if held:
            a.experiment = (missing[0] if missing else
                            f"the records already hold {held[0]}; a longer record or less noise would")
