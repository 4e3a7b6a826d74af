"""The in-silico trial's targets (issue 48), and where an in-process session's time goes.

1. **Success on the cohort** (per plant): ``rehab-hil trial`` with ``--controller assist_as_needed`` over
   ``profiles/sim/cohort.toml``, 20 patients x 1 session x 120 s by default. Target on the Finger
   Extensor: >= 90 % of the patients at >= 80 % success of the moves the rig drives, no safety event.
2. **Speed**: the trial's own wall time and simulated seconds per wall second on this machine's pool,
   extrapolated to the target's 100 patients x 3 sessions x 120 s (<= 15 min on 2 cores). Say
   ``--patients 100 --sessions 3`` to measure it whole instead.
3. ``--profile S``: one in-process session of S seconds (Finger Extensor, the shipped weak patient,
   assist_as_needed), recorded and not: its CPU time per loop cycle (no profiler), then cProfile's own
   self time per cycle while the session runs, grouped by where the code lives (cProfile slows every
   Python call several-fold, the small ones most: read the shares, not the absolute figures).

Not a test: prints and writes ``bench/results/trial.json``.

    PYTHONPATH=src python bench/trial.py                                   # 3 plants, 20 x 1 x 120 s
    PYTHONPATH=src python bench/trial.py --plants finger_extensor --patients 10 --sessions 3
    PYTHONPATH=src python bench/trial.py --plants none --profile 30
"""

from __future__ import annotations

import argparse
import cProfile
import json
import pstats
import tempfile
import time
from collections import defaultdict
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[1]
RESULTS = ROOT / "bench" / "results" / "trial.json"
TARGET_S = 15 * 60  # 100 patients x 3 sessions x 120 s on 2 cores (issue 48)
AREAS = (("service/", "host loop (service/)"), ("hardware/", "device side (hardware/, devices/)"),
         ("devices/", "device side (hardware/, devices/)"), ("patient/", "patient (truth file)"),
         ("engines/", "compiled engines (numba calls)"), ("models/", "model framework (models/)"),
         ("session_metrics", "session figures"), ("therapy_measures", "session figures"),
         ("control/", "controllers' parts (control/)"), ("threading", "threads (recorder wake-ups)"),
         ("mcap", "recorder (mcap)"), ("~:", "C calls (numba dispatch, locks, builtins)"))


def trial(plant: str, patients: int, sessions: int, duration_s: float, seed: int, out: Path,
          record: str = "all") -> dict[str, Any]:
    """One trial through the command (as a user runs it); its summary and timing."""
    from rehab_hil.cli import main

    folder = out / f"{plant}-{patients}x{sessions}x{duration_s:g}-{record}"
    t0 = time.perf_counter()
    code = main(["trial", "--config", str(ROOT / "configs" / f"{plant}.toml"), "--controller", "assist_as_needed",
                 "--patients", str(patients), "--sessions", str(sessions), "--duration", str(duration_s),
                 "--seed", str(seed), "--out", str(folder), "--record", record])
    wall = time.perf_counter() - t0
    doc = json.loads((folder / "trial.json").read_text())
    s = doc["summary"]
    simulated = sum(x["ran_s"] or 0.0 for p in doc["patients"] for x in p["sessions"])
    events = sum(len(x["safety_events"]) for p in doc["patients"] for x in p["sessions"])
    row = {"plant": plant, "record": record, "exit": code, "patients": patients, "sessions": sessions,
           "duration_s": duration_s, "seed": seed, "wall_s": wall, "simulated_s": simulated,
           "speed_x": simulated / wall, "met": s["met"],
           "met_share": s["met_share"], "errors": s["errors"], "safety_events": events,
           "strata": {k: {"met": g["met"], "patients": g["patients"], "median_success_assisted":
                          g["median_success_assisted"], "hottest_c": g["max_peak_temperature_c"]}
                      for k, g in s["strata"].items()},
           "failed": [{"id": p["id"], "stratum": p["stratum"],
                       "success_assisted": p["sessions"][-1]["success_assisted"] if p["sessions"] else None,
                       "assistance_end": p["sessions"][-1]["assistance_end"] if p["sessions"] else None,
                       "error": p["error"]} for p in doc["patients"] if not _met(p, s["target_success"])]}
    full = 100 * 3 * 120.0
    row["extrapolated_100x3x120_s"] = full / row["speed_x"]
    print(f"\n{plant} (--record {record}): {s['met']} of {patients} patients met the target "
          f"({s['met_share']:.0%}; issue: >= 90 %), safety events {events}, errors {s['errors']}")
    for k, g in row["strata"].items():
        print(f"  {k:9s} {g['met']} of {g['patients']}, median success (driven) {g['median_success_assisted']}, "
              f"hottest {g['hottest_c']} C")
    for f in row["failed"]:
        print(f"  failed: {f['id']} ({f['stratum']}) success {f['success_assisted']} assistance at the end "
              f"{f['assistance_end']} {f['error'] or ''}")
    print(f"  {wall:.0f} s wall for {simulated:.0f} s simulated: {row['speed_x']:.1f}x real time on the pool; "
          f"100 x 3 x 120 s would take {row['extrapolated_100x3x120_s'] / 60:.0f} min (target 15)")
    return row


def _met(p: dict[str, Any], target: float) -> bool:
    from rehab_hil.trial.results import meets_target

    return meets_target(p, target)


def _session(duration_s: float, record: Path | None,
             profiler: cProfile.Profile | None = None) -> tuple[float, float, int]:
    """(CPU s, wall s, loop cycles) of one session of the profile's kind; ``profiler`` on while it runs."""
    from rehab_hil.service.session import open_session

    with open_session(ROOT / "configs/finger_extensor.toml", "inprocess", controller="assist_as_needed",
                      sim_patient=ROOT / "profiles/sim/weak.toml", record=record, fresh_assistance=True,
                      assistance_store=Path(tempfile.mkdtemp())) as s:
        c0, t0 = time.process_time(), time.perf_counter()
        if profiler is not None:
            profiler.enable()
        result = s.run(duration_s)
        if profiler is not None:
            profiler.disable()
        return time.process_time() - c0, time.perf_counter() - t0, result.cycles


def profile(duration_s: float, out: Path) -> dict[str, Any]:
    """CPU per cycle recorded and not, then cProfile's self time per cycle by area."""
    _session(1.0, None)  # engines loaded
    rows: dict[str, Any] = {}
    for name, record in (("not recorded", None), ("recorded", out)):
        cpu, wall, cycles = min(_session(duration_s, record) for _ in range(2))
        rows[name] = {"cpu_us_per_cycle": cpu / cycles * 1e6, "wall_s": wall, "cycles": cycles,
                      "cpu_speed_x": duration_s / cpu}
        print(f"session {name}: {cpu / cycles * 1e6:.0f} us CPU per cycle ({duration_s / cpu:.1f}x real time "
              f"on one core's CPU), wall {wall:.1f} s")
    for name, record in (("not recorded", None), ("recorded", out)):
        pr = cProfile.Profile()
        _, _, cycles = _session(duration_s, record, pr)
        areas: dict[str, float] = defaultdict(float)
        for (file, _, func), (_, _, tottime, _, _) in pstats.Stats(pr).stats.items():  # type: ignore[attr-defined]
            where = f"{file}:{func}"
            areas[next((label for key, label in AREAS if key in where), "other Python")] += tottime
        total = sum(areas.values())
        rows[name]["cprofile_us_per_cycle"] = {k: v / cycles * 1e6 for k, v in areas.items()}
        print(f"cProfile, {name} ({total / cycles * 1e6:.0f} us per cycle under the profiler):")
        for k, v in sorted(areas.items(), key=lambda kv: -kv[1]):
            print(f"  {k:40s} {v / cycles * 1e6:6.1f} us  {v / total:5.1%}")
    return rows


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--plants", default="finger_extensor,sma_exoskeleton,tcp_finger", help="or 'none'")
    ap.add_argument("--patients", type=int, default=20)
    ap.add_argument("--sessions", type=int, default=1)
    ap.add_argument("--duration", type=float, default=120.0)
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--record", default="all", help="all, failed, or both (each trial twice)")
    ap.add_argument("--out", type=Path, default=None, help="keep the trials here (default: a temporary folder)")
    ap.add_argument("--profile", type=float, default=0.0, metavar="S", help="also profile an S s session")
    ap.add_argument("--json", type=Path, default=RESULTS)
    args = ap.parse_args()
    result: dict[str, Any] = {"trials": []}
    with tempfile.TemporaryDirectory() as tmp:
        out = args.out or Path(tmp)
        for plant in [p for p in args.plants.split(",") if p and p != "none"]:
            for record in (("all", "failed") if args.record == "both" else (args.record,)):
                result["trials"].append(trial(plant, args.patients, args.sessions, args.duration, args.seed, out,
                                              record))
        if args.profile:
            result["profile"] = profile(args.profile, out / "profiled")
    args.json.parent.mkdir(parents=True, exist_ok=True)
    args.json.write_text(json.dumps(result, indent=1, default=float))
    print(f"\nwrote {args.json}")


if __name__ == "__main__":
    main()
