"""Learning on the rig (issue 39 item 1): a plant's shipped session on rigs that differ from the host's
model, with the model-learned feedforward alone and with the learning on the rig, cycle by cycle.

Each rig is the shipped config with one value changed (the simulated device runs it through
``--sim-plant``; the host keeps the shipped model): for the SMA exoskeleton the room 7 C warmer, the
supply 10 % low, the wire's pre-strain 15 % lower, 30 % more convection (h1 and h2 x 1.3, a
draft), and the nominal rig. Every session is built by ``open_session`` on the in-process device
(lockstep, deterministic) with a fresh table store, so no session starts from another's learning.
Per cycle: the tracking RMSE, the host's peak temperature estimate, and (learning) the observer's
predicted peak for the table in force and the share of each update kept; any safety event.

Targets (issue 39): no safety event; SMA RMSE <= 1 deg over cycles 3 onward and <= 0.5 deg by
cycle 10, estimated wire <= 103 C; the nominal rig no worse with the learning than without.
Prints a table per rig and writes bench/results/rig_learning.json.
Usage: python bench/rig_learning.py [--duration 150] [--rigs nominal,warm,...] [--plant sma_exoskeleton]
"""

from __future__ import annotations

import argparse
import json
import math
import re
import tempfile
import time
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[1]

# rig variants: name -> [(key in the config's text, how it changes)]
SMA_RIGS: dict[str, list[tuple[str, Any]]] = {
    "nominal": [],
    "room +7 C": [("ambient_c", lambda v: v + 7.0)],
    "supply -10 %": [("supply_voltage_v", lambda v: v * 0.9)],
    "prestrain -15 %": [("prestrain", lambda v: v * 0.85)],
    "convection +30 %": [("h1_w_per_m2_c", lambda v: v * 1.3), ("h2_w_per_m2_c3", lambda v: v * 1.3)],
}


def variant(base: Path, changes: list[tuple[str, Any]], out: Path) -> Path:
    """``base`` with the first ``key = number`` of each change rewritten (the first is the plant's own:
    ``[sma] ambient_c`` comes before ``[rig.thermal] ambient_c``, the host's estimate, left as it is)."""
    text = base.read_text()
    for key, change in changes:
        pat = re.compile(rf"^({re.escape(key)}\s*=\s*)([0-9.eE+-]+)", re.M)
        m = pat.search(text)
        if m is None:
            raise SystemExit(f"{base}: no {key}")
        text = text[:m.start(2)] + repr(change(float(m.group(2)))) + text[m.end(2):]
    out.write_text(text)
    return out


def session(config: Path, sim: Path | None, duration_s: float, learning: bool, store: Path) -> dict[str, Any]:
    """One session on the in-process rig; its per-cycle figures, events and learning summary."""
    from rehab_hil.service.session import open_session

    t0 = time.perf_counter()
    with open_session(config, "inprocess", sim_plant=sim, rig_learning=learning, learning_store=store) as s:
        r = s.run(duration_s)
    return {"cycles": r.session_cycles, "events": [f"{e.reason} at {e.t_s:.1f} s" for e in r.events],
            "learning": r.learning, "stop_reason": r.stop_reason, "wall_s": time.perf_counter() - t0}


def figures(cycles: list[dict[str, Any]]) -> dict[str, float]:
    """The issue's figures: RMSE over cycles 3 onward (index 2 on), at cycle 10, the worst peak estimate."""
    rmse = [c["rmse_deg"] for c in cycles]
    later = rmse[2:]
    return {"rmse_3_on_max_deg": max(later) if later else math.nan,
            "rmse_3_on_mean_deg": sum(later) / len(later) if later else math.nan,
            "rmse_cycle_10_deg": rmse[9] if len(rmse) >= 10 else math.nan,
            "peak_estimate_c": max((c["peak_temperature_c"] for c in cycles), default=math.nan),
            "learn_predicted_peak_c": max((c.get("learn_predicted_peak_c", math.nan) for c in cycles),
                                          default=math.nan)}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--duration", type=float, default=150.0, help="session length [s] (12 s cycles: 150 s = 12)")
    ap.add_argument("--rigs", default=",".join(SMA_RIGS), help="comma-separated rig names")
    ap.add_argument("--config", type=Path, default=ROOT / "configs" / "sma_exoskeleton.toml")
    ap.add_argument("--learning-only", action="store_true", help="skip the model-only sessions (settings trials)")
    ap.add_argument("--out", type=Path, default=ROOT / "bench" / "results" / "rig_learning.json")
    args = ap.parse_args()
    results: dict[str, Any] = {}
    with tempfile.TemporaryDirectory() as tmp:
        for name in args.rigs.split(","):
            sim = variant(args.config, SMA_RIGS[name], Path(tmp) / f"rig-{len(results)}.toml") if SMA_RIGS[name] \
                else None
            row = {}
            for learning in (True,) if args.learning_only else (False, True):
                got = session(args.config, sim, args.duration, learning, Path(tmp) / f"store-{name}-{learning}")
                got["figures"] = figures(got["cycles"])
                row["learning" if learning else "model_only"] = got
                rm = " ".join(f"{c['rmse_deg']:.2f}" for c in got["cycles"])
                f = got["figures"]
                print(f"{name:18s} {'learning ' if learning else 'model    '} RMSE/cycle [{rm}]  peak est "
                      f"{f['peak_estimate_c']:.1f} C  predicted {f['learn_predicted_peak_c']:.1f} C  events "
                      f"{got['events'] or 'none'}  ({got['wall_s']:.0f} s)", flush=True)
            results[name] = row
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(results, indent=1, default=str) + "\n")


if __name__ == "__main__":
    main()
