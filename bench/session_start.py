"""What a short session on the simulated rig costs from the command to its end: wall time and the CPU of
the command and all its processes, with the device and loop processes forked from the warm zygote
(``rehab_hil.launch``) beside the same started as fresh interpreters (``REHAB_HIL_ZYGOTE=0``).

    python bench/session_start.py                      # 5 runs each way, a 1 s Finger Extensor session
    python bench/session_start.py --runs 3 --config configs/sma_exoskeleton.toml
    python bench/session_start.py --sessions 5       # five sessions in one process (a test, a user's script)

Prints a table (median and range) and writes bench/results/session_start.json.
"""

from __future__ import annotations

import argparse
import ctypes
import json
import os
import resource
import statistics
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
PR_SET_CHILD_SUBREAPER = 36  # linux/prctl.h


def adopt_orphans() -> None:
    """Make this process the reaper of its descendants' orphans (the zygote outlives the command by a
    moment): their CPU then counts in this process's children's usage once reaped."""
    ctypes.CDLL(None, use_errno=True).prctl(PR_SET_CHILD_SUBREAPER, 1, 0, 0, 0)


def reap_all() -> None:
    while True:
        try:
            os.waitpid(-1, 0)
        except ChildProcessError:
            return


SESSIONS = """import sys
from rehab_hil.service.session import open_session
for _ in range(int(sys.argv[3])):
    with open_session(sys.argv[1], "sim") as s:
        s.run(float(sys.argv[2]))
"""


def one_run(config: str, duration_s: float, zygote: bool, sessions: int) -> tuple[float, float]:
    """(wall s, CPU s of the command and all its descendants) of one ``rehab-hil run`` (``sessions`` 0), or
    of a script that opens ``sessions`` sessions one after the other (``service.session.open_session``)."""
    env = {**os.environ, "REHAB_HIL_ZYGOTE": "1" if zygote else "0"}
    argv = ([sys.executable, "-c", SESSIONS, config, str(duration_s), str(sessions)] if sessions else
            [sys.executable, "-m", "rehab_hil.cli", "run", "--config", config, "--device", "sim",
             "--duration", str(duration_s), "--no-display"])
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.monotonic()
    subprocess.run(argv, cwd=ROOT, env=env, check=True, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    wall = time.monotonic() - t0
    reap_all()
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    cpu = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
    return wall, cpu


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--runs", type=int, default=5)
    ap.add_argument("--config", default="configs/finger_extensor.toml")
    ap.add_argument("--duration", type=float, default=1.0)
    ap.add_argument("--sessions", type=int, default=0,
                    help="N sessions one after the other in one Python process (0: one rehab-hil run command)")
    args = ap.parse_args()
    adopt_orphans()
    one_run(args.config, args.duration, True, 0)  # the engines in the cache, the files in the page cache
    got: dict[str, dict[str, list[float]]] = {}
    for _ in range(args.runs):
        for name, zygote in (("zygote", True), ("fresh interpreters", False)):
            wall, cpu = one_run(args.config, args.duration, zygote, args.sessions)
            got.setdefault(name, {"wall_s": [], "cpu_s": []})
            got[name]["wall_s"].append(wall)
            got[name]["cpu_s"].append(cpu)
    what = f"{args.sessions} sessions in one process" if args.sessions else "rehab-hil run"
    print(f"{what} --device sim --duration {args.duration:g} ({args.config}), {args.runs} runs each")
    print(f"{'children':<20} {'wall s (median, range)':<26} {'CPU s (median, range)':<26}")
    for name, figures in got.items():
        cells = [f"{statistics.median(v):.2f} ({min(v):.2f}-{max(v):.2f})" for v in figures.values()]
        print(f"{name:<20} {cells[0]:<26} {cells[1]:<26}")
    out = ROOT / "bench" / "results" / f"session_start{'_x' + str(args.sessions) if args.sessions else ''}.json"
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps({"config": args.config, "duration_s": args.duration, "sessions": args.sessions,
                               "runs": got}, indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main())
