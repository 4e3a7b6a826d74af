"""How much faster than real time a lockstep session runs, per device and plant (issue 25: >= 5x over a pty).

Runs ``rehab-hil run --lockstep`` as a user would (recording on, the session's own controller) on
each plant config against the Python simulated device and the firmware in simavr, both over a real
pty, and the in-process device (no pty, the fastest a session can go) beside them; a real-time run
of the Python device is the alternative a user has without lockstep (1x, shown to check the
figure). Speed is the run's own ``timing.speed_x`` in metadata.json: device time the samples
covered over the host time the loop's cycles took. The command's whole wall time (start-up,
connecting, the plan from its cache, shutdown) is printed beside it. Not a test: it prints and
writes ``bench/results/lockstep_speed.json``.

    .venv/bin/python bench/lockstep_speed.py                    # 3 plants x 4 ways, 20 s sessions, 2 repeats
    .venv/bin/python bench/lockstep_speed.py --plants sma_exoskeleton --repeats 1
    .venv/bin/python bench/lockstep_speed.py --base 433edda --ways "sim, lockstep (pty)"   # before/after
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from loop_reaction import base_tree  # src/ of a commit, unpacked: the "before" of --base

ROOT = Path(__file__).resolve().parents[1]
RESULTS = ROOT / "bench" / "results" / "lockstep_speed.json"
CLI = [sys.executable, "-m", "rehab_hil.cli"]
WAYS = {  # name: extra arguments of rehab-hil run
    "sim, lockstep (pty)": ["--device", "sim", "--lockstep"],
    "avr, lockstep (pty)": ["--device", "avr", "--lockstep"],
    "inprocess (no pty)": ["--device", "inprocess"],
    "sim, real time": ["--device", "sim"],
}


def one(plant: str, way: str, duration_s: float, folder: Path, twin: bool, src: Path | None = None) -> dict:
    out = folder / f"{plant}-{way.split(',')[0].split()[0]}-{time.monotonic_ns()}"
    cmd = [*CLI, "run", "--config", str(ROOT / "configs" / f"{plant}.toml"), *WAYS[way], "--duration",
           str(duration_s), "--no-display", "--record", str(out), *(["--twin"] if twin else [])]
    t0 = time.perf_counter()
    env = {**os.environ, "PYTHONPATH": str(src)} if src is not None else None  # --base: that tree's code
    p = subprocess.run(cmd, capture_output=True, text=True, cwd=ROOT, env=env)
    whole = time.perf_counter() - t0
    metas = list(out.glob("*/metadata.json"))
    if p.returncode != 0 or not metas:
        return {"plant": plant, "way": way, "error": (p.stderr or p.stdout)[-400:]}
    tm = json.loads(metas[0].read_text())["timing"]
    return {"plant": plant, "way": way, "speed_x": tm["speed_x"], "loop_wall_s": tm["wall_s"],
            "device_s": tm["device_s"], "command_wall_s": whole, "load": os.getloadavg()[0]}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--plants", nargs="+", default=["finger_extensor", "tcp_finger", "sma_exoskeleton"])
    ap.add_argument("--duration", type=float, default=20.0, help="device time per session [s]")
    ap.add_argument("--repeats", type=int, default=2)
    ap.add_argument("--twin", action="store_true", help="with the live twin beside the loop (make run's flag)")
    ap.add_argument("--ways", nargs="+", default=list(WAYS), choices=list(WAYS), metavar="WAY")
    ap.add_argument("--base", default=None, metavar="COMMIT",
                    help="also run each session with the code of COMMIT ('before'), alternating with this tree")
    ap.add_argument("--out", type=Path, default=RESULTS)
    args = ap.parse_args()
    rows = []
    print(f"load {os.getloadavg()[0]:.2f} at the start; {args.duration:g} s sessions, {args.repeats} repeats, "
          f"recording on{', twin on' if args.twin else ''}", flush=True)
    with tempfile.TemporaryDirectory(prefix="lockstep-speed-") as tmp:
        trees = {"": None} if args.base is None else {"before": base_tree(Path(tmp), args.base), "after": None}
        for _ in range(args.repeats):  # repeats outermost: a change of load falls on every way
            for plant in args.plants:
                for way in args.ways:
                    for tree, src in trees.items():
                        r = one(plant, way, args.duration, Path(tmp), args.twin, src)
                        r["way"] = f"{way} {tree}".strip()
                        rows.append(r)
                        print(f"  {plant:16s} {r['way']:29s} " + (
                            f"{r['speed_x']:6.2f}x  loop {r['loop_wall_s']:6.2f} s, "
                            f"command {r['command_wall_s']:6.2f} s"
                            if "speed_x" in r else f"FAILED {r['error']!r}"), flush=True)
        ways = [f"{w} {t}".strip() for w in args.ways for t in trees]
    print(f"\nload {os.getloadavg()[0]:.2f} at the end. Median speed over {args.repeats} runs (range), x real time:")
    print("| plant | " + " | ".join(ways) + " |")
    print("| --- |" + " --- |" * len(ways))
    for plant in args.plants:
        cells = []
        for way in ways:
            v = [r["speed_x"] for r in rows if r["plant"] == plant and r["way"] == way and "speed_x" in r]
            cells.append(f"{statistics.median(v):.2f} ({min(v):.2f}-{max(v):.2f})" if v else "failed")
        print(f"| {plant} | " + " | ".join(cells) + " |")
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps({"duration_s": args.duration, "twin": args.twin, "base": args.base, "runs": rows},
                                   indent=1))
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
