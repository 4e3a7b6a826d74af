"""``rehab-hil report``: a self-contained HTML report of recorded sessions (rehab_hil.report)."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path


def add_parser(sub: argparse._SubParsersAction) -> argparse.ArgumentParser:
    p = sub.add_parser("report", help="an HTML report of a recorded session, or the progress across several")
    p.add_argument("runs", nargs="+", type=Path, metavar="RUN_DIR",
                   help="run directories of `rehab-hil run --record DIR` (or DIR itself: all its runs)")
    p.add_argument("--out", type=Path, default=None, metavar="FILE",
                   help="the HTML file (default: report.html in the run directory; for several runs "
                        "progress.html in their common folder)")
    return p


def run(args: argparse.Namespace) -> int:
    from rehab_hil.cli import UserError
    from rehab_hil.report.build import default_output, report_page
    from rehab_hil.report.runs import ReportError, find_runs, load_run

    try:
        found = {p: find_runs(p) for p in args.runs}
        for p, ds in found.items():  # a folder of runs: which it holds, so a stray file is seen to be left out
            if p.is_dir() and ds != [p]:
                print(f"rehab-hil report: {p} holds {len(ds)} run{'s' * (len(ds) > 1)}: "
                      + ", ".join(d.name for d in ds[:6]) + (" ..." if len(ds) > 6 else ""), file=sys.stderr)
        dirs = list(dict.fromkeys(d for ds in found.values() for d in ds))
        dirs.sort(key=lambda d: d.name)  # run directories start with their UTC start time
        runs = [load_run(d) for d in dirs]
        page = report_page(runs)
    except ReportError as e:
        raise UserError(str(e)) from None
    out = args.out or default_output(dirs)
    if out.is_dir():
        out = out / ("report.html" if len(dirs) == 1 else "progress.html")
    try:
        page.write(out)
    except OSError as e:
        raise UserError(f"--out {out}: cannot write: {e.strerror}") from None
    for r in runs:
        for note in r.notes:
            print(f"rehab-hil report: warning: {note}")
    what = f"run {dirs[0]}" if len(dirs) == 1 else f"{len(dirs)} runs, {dirs[0].name} .. {dirs[-1].name}"
    print(f"wrote {out} ({out.stat().st_size / 1e6:.2f} MB, {page.n_figures} plots): {what}")
    return 0
