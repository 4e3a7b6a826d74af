"""The HTML session report of a 10 min 1 kHz session: file size, time to build, and time to draw
in headless Chromium (targets: <= 5 MB, <= 3 s to draw; issue 26).

Records a 600 s model-based session on the in-process SMA rig (``rehab-hil run --device inprocess
--record``) unless ``--run RUN_DIR`` names one, writes its report, then opens it ``--repeat`` times
in a fresh Chromium each (rehab_hil.report.browser): navigation start to every plot drawn, from
the page's own clock, with the stages (plotly.js unpacked, plotly.js evaluated). Prints the
figures, the machine's load average, and writes bench/results/report_render.json.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import statistics
import tempfile
import time
from pathlib import Path

import plotly.graph_objects as go

from rehab_hil.cli import main as cli
from rehab_hil.report.browser import check_page
from rehab_hil.report.build import report_page
from rehab_hil.report.page import Page
from rehab_hil.report.runs import load_run

ROOT = Path(__file__).resolve().parents[1]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--run", type=Path, default=None, help="an existing run directory (default: record one)")
    ap.add_argument("--duration", type=float, default=600.0, help="session length to record [s]")
    ap.add_argument("--repeat", type=int, default=5)
    args = ap.parse_args()
    run_dir = args.run
    if run_dir is None:
        root = Path(tempfile.mkdtemp(prefix="report-bench-"))
        cli(["run", "--config", str(ROOT / "configs/sma_exoskeleton.toml"), "--device", "inprocess",
             "--duration", str(args.duration), "--record", str(root), "--no-display"])
        (run_dir,) = root.iterdir()
    t0 = time.perf_counter()
    run = load_run(run_dir)
    t1 = time.perf_counter()
    page = report_page([run])
    out = page.write(run_dir / "report.html")
    t2 = time.perf_counter()
    # the floor: the same kind of page with one three-point plot (unpacking and evaluating plotly.js)
    base = Page("baseline: plotly.js and one tiny plot")
    base.figure(go.Figure(go.Scatter(y=[1, 2, 3])))
    base_path = base.write(Path(tempfile.mkdtemp(prefix="report-bench-")) / "baseline.html")
    checks, floor = [], []
    for _ in range(args.repeat):  # interleaved, so both see the same machine load
        checks.append(check_page(out))
        floor.append(check_page(base_path))
    drawn = [c.drawn_ms for c in checks if c.state == "drawn" and c.drawn_ms is not None]
    res = {
        "run": str(run_dir), "samples": int(run.t.size), "duration_s": float(run.t[-1]),
        "csv_mb": (run_dir / "run.csv").stat().st_size / 1e6, "report_bytes": out.stat().st_size,
        "report_mb": out.stat().st_size / 1e6, "plots": page.n_figures, "read_s": t1 - t0, "build_s": t2 - t1,
        "states": [c.state for c in checks], "console_errors": sum(len(c.errors) for c in checks),
        "drawn_ms": drawn, "drawn_ms_median": statistics.median(drawn) if drawn else None,
        "stages_ms": [c.stages_ms for c in checks], "baseline_drawn_ms": [c.drawn_ms for c in floor],
        "baseline_drawn_ms_median": statistics.median([c.drawn_ms for c in floor if c.drawn_ms is not None] or [0]),
        "loadavg": os.getloadavg(), "cpus": os.cpu_count(),
        "machine": platform.platform(),
    }
    print(f"{run_dir}: {res['samples']} samples over {res['duration_s']:.0f} s (run.csv {res['csv_mb']:.1f} MB)")
    print(f"report {res['report_bytes']} bytes ({res['report_mb']:.2f} MB), {res['plots']} plots; read "
          f"{res['read_s']:.2f} s, build {res['build_s']:.2f} s")
    print(f"drawn in Chromium: {', '.join(f'{d:.0f}' for d in drawn)} ms (median {res['drawn_ms_median']} ms); "
          f"console errors {res['console_errors']}; load average {res['loadavg'][0]:.2f} on {res['cpus']} cpus")
    print(f"baseline (plotly.js and one tiny plot, same page kind): {res['baseline_drawn_ms']} ms "
          f"(median {res['baseline_drawn_ms_median']} ms)")
    (ROOT / "bench/results").mkdir(exist_ok=True)
    (ROOT / "bench/results/report_render.json").write_text(json.dumps(res, indent=2) + "\n")


if __name__ == "__main__":
    main()
