"""The whole `make test` on fresh clones of `main`, repeated, each run beside busy processes (issue 25).

CI runs `make test` on a developer's machine right after a session, while other work may still run.
This runs it as CI does (`git clone` of the repository's HEAD into a new folder, then `make test`,
which creates its own venv), N times, each beside `--busy` processes that spin a core each
(`sh -c 'while :; do :; done'`, killed after the run), and prints one line per run: pass or fail,
the pytest summary line, its wall time and make's, the 1-minute load average at the start and the
end. A failed run's failing tests are listed. Not a test: it prints and writes
``bench/results/suite_under_load.json``.

    .venv/bin/python bench/suite_under_load.py --runs 10 --busy 2
    .venv/bin/python bench/suite_under_load.py --runs 1 --busy 0      # idle: make test's own time
"""

from __future__ import annotations

import argparse
import json
import os
import re
import shutil
import subprocess
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
RESULTS = ROOT / "bench" / "results" / "suite_under_load.json"
BUSY = ["sh", "-c", "while :; do :; done"]
_SUMMARY = re.compile(r"^=+ (.*(passed|failed|error).*) in ([\d.]+)s", re.M)
_FAILED = re.compile(r"^(FAILED|ERROR) (\S+)", re.M)


def one_run(index: int, busy: int, keep: bool) -> dict:
    """A fresh clone of HEAD, `make test` in it beside ``busy`` spinning processes."""
    head = subprocess.run(["git", "-C", str(ROOT), "rev-parse", "--short", "HEAD"], capture_output=True, text=True,
                          check=True).stdout.strip()
    folder = Path(tempfile.mkdtemp(prefix=f"suite-load-{index}-"))
    subprocess.run(["git", "clone", "-q", str(ROOT), str(folder / "repo")], check=True)
    spinners = [subprocess.Popen(BUSY, start_new_session=True) for _ in range(busy)]
    load0 = os.getloadavg()[0]
    t0 = time.perf_counter()
    try:
        p = subprocess.run(["make", "test"], cwd=folder / "repo", capture_output=True, text=True)
    finally:
        for s in spinners:
            os.killpg(s.pid, 9)
            s.wait()
    wall = time.perf_counter() - t0
    out = p.stdout + p.stderr
    m = _SUMMARY.findall(out)
    row = {"run": index, "commit": head, "busy": busy, "returncode": p.returncode, "make_s": round(wall, 1),
           "pytest_summary": m[-1][0] if m else None, "pytest_s": float(m[-1][2]) if m else None,
           "load_start": round(load0, 2), "load_end": round(os.getloadavg()[0], 2),
           "failed": [f"{k} {n}" for k, n in _FAILED.findall(out)], "reruns": out.count(" RERUN")}
    if p.returncode != 0:
        log = RESULTS.with_name(f"suite_under_load-run{index}.log")
        log.parent.mkdir(parents=True, exist_ok=True)
        log.write_text(out)
        row["log"] = str(log)
    if not keep:
        shutil.rmtree(folder, ignore_errors=True)
    return row


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--runs", type=int, default=10)
    ap.add_argument("--busy", type=int, default=2, help="spinning processes beside each run (one per core: 2)")
    ap.add_argument("--keep", action="store_true", help="keep the clones")
    ap.add_argument("--out", type=Path, default=RESULTS)
    args = ap.parse_args()
    rows = []
    print(f"make test on fresh clones of {ROOT} HEAD, {args.runs} runs, {args.busy} busy processes beside each "
          f"({' '.join(BUSY)})", flush=True)
    for i in range(1, args.runs + 1):
        r = one_run(i, args.busy, args.keep)
        rows.append(r)
        verdict = "PASS" if r["returncode"] == 0 else "FAIL"
        print(f"run {i:2d} {r['commit']}: {verdict}  {r['pytest_summary']}  pytest {r['pytest_s']} s, make "
              f"{r['make_s']} s, load {r['load_start']} -> {r['load_end']}, reruns {r['reruns']}"
              + (f"\n        failed: {', '.join(r['failed'])} (log {r.get('log')})" if r["failed"] else ""),
              flush=True)
        args.out.parent.mkdir(parents=True, exist_ok=True)
        args.out.write_text(json.dumps({"busy": args.busy, "command": " ".join(BUSY), "runs": rows}, indent=1))
    passed = sum(r["returncode"] == 0 for r in rows)
    make = sorted(r["make_s"] for r in rows)
    print(f"\n{passed} of {len(rows)} passed beside {args.busy} busy processes; make test {make[0]}-{make[-1]} s "
          f"(median {make[len(make) // 2]} s); wrote {args.out}")


if __name__ == "__main__":
    main()
