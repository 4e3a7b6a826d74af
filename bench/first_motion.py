"""How long ``make run`` takes on a clean machine before the session starts and the rig first
moves: this tree beside another revision (default: before the part modules, as bench/engine_compile.py).

The command is the Makefile's ``run`` recipe (the SMA exoskeleton on the simulated rig with the live
twin) with ``--duration`` shortened and ``--record`` sent to a temporary folder, run with this
interpreter, ``PYTHONPATH`` the tree's ``src`` and ``REHAB_HIL_CACHE_DIR`` and ``NUMBA_CACHE_DIR``
empty (nothing compiled, no plan learned). Measured from the command's start on the system's monotonic
clock, which the recording's ``host_time_s`` reads too: the session's first sample, and the first
sample whose commanded duty is above zero (the rig moves). ``cpu`` is the CPU time of the command and
its simulated device, what an idle two-core machine would mostly wait for. With ``--warm`` the command
runs once more on the caches the first run filled. Prints a table and writes
bench/results/first_motion.json.

    python bench/first_motion.py                     # this tree beside the engine before the split
    python bench/first_motion.py --against none      # this tree alone
"""

from __future__ import annotations

import argparse
import csv
import json
import os
import re
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
BEFORE_SPLIT = "32250d9"  # the engine that inlined every kernel into each structure's module


def make_run_args(duration_s: float, record: Path) -> list[str]:
    """The Makefile's ``run`` recipe as ``rehab-hil`` arguments, with ``duration_s`` and ``record``."""
    recipe = re.search(r"^run:.*\n(?:\t.*\n)*?\t\$\(BIN\)/rehab-hil (.+)$", (ROOT / "Makefile").read_text(), re.M)
    assert recipe, "no run recipe in the Makefile"
    args = recipe.group(1).split()
    args[args.index("--duration") + 1] = f"{duration_s:g}"
    args[args.index("--record") + 1] = str(record)
    return args


def first_motion(src: Path, cache: Path, duration_s: float) -> dict:
    """One run of the command on ``cache``: seconds to the session's start and to the first duty."""
    record = cache / "out"
    env = {**os.environ, "PYTHONPATH": str(src), "REHAB_HIL_CACHE_DIR": str(cache / "rh"),
           "NUMBA_CACHE_DIR": str(cache / "numba")}
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.monotonic()
    proc = subprocess.run([sys.executable, "-m", "rehab_hil.cli", *make_run_args(duration_s, record)],
                          cwd=ROOT, env=env, capture_output=True, text=True)
    wall = time.monotonic() - t0
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    runs = sorted(record.glob("*/run.csv"))
    if not runs:
        raise SystemExit(f"no recording (exit {proc.returncode}): {proc.stdout[-2000:]}{proc.stderr[-2000:]}")
    with runs[-1].open() as f:
        rows = list(csv.DictReader(f))
    start = float(rows[0]["host_time_s"]) - t0
    moving = next((float(r["host_time_s"]) - t0 for r in rows if float(r["command_duty0_ratio"] or 0) > 0), None)
    return {"session_start_s": start, "first_duty_s": moving, "command_s": wall, "exit": proc.returncode,
            "cpu_s": (after.ru_utime + after.ru_stime) - (before.ru_utime + before.ru_stime),
            "trips": [line for line in proc.stdout.splitlines() if "safety trip" in line]}


def _export(rev: str, into: Path) -> Path:
    tar = subprocess.run(["git", "-C", str(ROOT), "archive", rev, "src"], capture_output=True, check=True).stdout
    subprocess.run(["tar", "-x", "-C", str(into)], input=tar, check=True)
    return into / "src"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--against", default=BEFORE_SPLIT, help="the revision to compare with (git), or 'none'")
    ap.add_argument("--duration", type=float, default=10.0, help="the session's --duration [s]")
    ap.add_argument("--warm", action="store_true", help="run each tree once more on its filled caches")
    args = ap.parse_args()
    results: dict[str, dict] = {}
    with tempfile.TemporaryDirectory(prefix="first_motion_") as tmp:
        trees = {"this tree": ROOT / "src"}
        if args.against != "none":
            trees[args.against] = _export(args.against, Path(tmp))
        for label, src in trees.items():
            cache = Path(tmp) / label.replace(" ", "_")
            results[label] = {"cold": first_motion(src, cache, args.duration)}
            if args.warm:
                for old in (cache / "out").iterdir():
                    old.rename(cache / f"cold_{old.name}")
                results[label]["warm"] = first_motion(src, cache, args.duration)
    print(f"{'':12s} {'':5s} {'session start':>14s} {'first duty':>11s} {'cpu':>8s}  trips")
    for label, r in results.items():
        for kind, m in r.items():
            duty = f"{m['first_duty_s']:9.1f} s" if m["first_duty_s"] is not None else "     none"
            print(f"{label:12s} {kind:5s} {m['session_start_s']:12.1f} s {duty} {m['cpu_s']:6.1f} s  "
                  f"{len(m['trips'])}")
    print(f"load average {os.getloadavg()[0]:.1f} on {os.cpu_count()} cores; target: moving within 60 s")
    path = ROOT / "bench" / "results" / "first_motion.json"
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps({"benchmark": "first_motion", "duration_s": args.duration,
                                "load_average": os.getloadavg()[0], "results": results}, indent=2))
    print(f"wrote {path}")


if __name__ == "__main__":
    main()
