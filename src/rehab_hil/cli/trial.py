"""``rehab-hil trial``: a controller run over a virtual cohort of simulated patients (``rehab_hil.trial``),
each patient's sessions on the in-process rig, on a local process pool or a Dask cluster."""

from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path
from typing import Any

from rehab_hil.cli import UserError, config_file, writable_folder

MAX_PATIENTS = 100_000
MAX_SESSIONS = 1000


def add_parser(sub: argparse._SubParsersAction) -> argparse.ArgumentParser:
    p = sub.add_parser("trial", help="an in-silico trial: a controller over a virtual cohort of simulated patients")
    p.add_argument("--config", required=True, type=config_file, help="the plant config (configs/*.toml)")
    p.add_argument("--controller", default=None, metavar="NAME",
                   help="the controller (e.g. assist_as_needed); default: [rig.session] controller")
    p.add_argument("--cohort", type=config_file, default=Path("profiles/sim/cohort.toml"), metavar="FILE",
                   help="the cohort file (default profiles/sim/cohort.toml; docs/patient.md)")
    p.add_argument("--patients", type=int, default=20, metavar="N", help="patients drawn from the cohort (default 20)")
    p.add_argument("--sessions", type=int, default=1, metavar="K",
                   help="sessions per patient, the learned assistance carried from one to the next (default 1)")
    p.add_argument("--duration", type=float, default=120.0, metavar="S", help="each session's length [s] (default 120)")
    p.add_argument("--seed", type=int, default=0, metavar="N",
                   help="the trial's seed: each patient's is derived from it (default 0)")
    p.add_argument("--out", type=Path, required=True, metavar="DIR",
                   help="a new folder: trial.json, trial.html, patients/<id>/ (profile, run folders, stores)")
    p.add_argument("--scheduler", default=None, metavar="ADDRESS",
                   help="run on the Dask cluster whose scheduler is at ADDRESS (tcp://host:port) instead of a "
                        "local process pool; its workers must see --out and the config at the same paths")
    p.add_argument("--workers", type=int, default=None, metavar="N",
                   help="the local pool's processes (default: the machine's cores)")
    p.add_argument("--twin", action="store_true",
                   help="run the live twin beside each session (its model-based patient torque; slower)")
    p.add_argument("--record", choices=("all", "failed"), default="all",
                   help="run folders of every session (default), or only of the patients who miss the target: "
                        "their sessions run again, recorded (lockstep sessions repeat exactly); faster")
    p.add_argument("--target-success", type=float, default=0.8, metavar="SHARE",
                   help="success of the moves the rig drives a patient must reach (default 0.8)")
    return p


def _check(args: argparse.Namespace) -> None:
    """What can be refused before anything runs, each in one line on its option."""
    if not 1 <= args.patients <= MAX_PATIENTS:
        raise UserError(f"--patients: must be 1..{MAX_PATIENTS}, got {args.patients}")
    if not 1 <= args.sessions <= MAX_SESSIONS:
        raise UserError(f"--sessions: must be 1..{MAX_SESSIONS}, got {args.sessions}")
    if not (math.isfinite(args.duration) and 0 < args.duration <= 24 * 3600):
        raise UserError(f"--duration: must be in (0, 86400] s, got {args.duration}")
    if not 0 <= args.seed < 2**63:
        raise UserError(f"--seed: must be 0..2^63-1, got {args.seed}")
    if args.workers is not None and not 1 <= args.workers <= 1024:
        raise UserError(f"--workers: must be 1..1024, got {args.workers}")
    if not 0.0 <= args.target_success <= 1.0:
        raise UserError(f"--target-success: must be in [0, 1], got {args.target_success}")
    if args.scheduler is not None and args.workers is not None:
        raise UserError("--workers: the local pool's size; with --scheduler the cluster's workers run the patients")
    out: Path = args.out
    if (out / "trial.json").exists() or (out / "patients").exists():
        raise UserError(f"--out {out}: holds a trial already (its patients' stored assistance would carry "
                        "over); give a new folder")


def _controller(args: argparse.Namespace) -> str:
    """The controller's name, refused now (one line) if it does not apply to the plant or would trip a
    limit on the model, instead of once per patient."""
    from rehab_hil.controllers import build
    from rehab_hil.loading import load_config

    cfg = load_config(args.config)
    controller = build.build_controller(cfg, args.controller, source=str(args.config))
    return controller.name


def run(args: argparse.Namespace) -> int:
    from rehab_hil.trial.cohort import load_cohort
    from rehab_hil.trial.driver import TRIAL_PAGE, run_trial
    from rehab_hil.trial.run import TrialSpec

    _check(args)
    cohort = load_cohort(args.cohort)
    name = _controller(args)
    if args.scheduler:
        _check_scheduler(args.scheduler)
    writable_folder(args.out, "--out", "the trial writes trial.json, trial.html and patients/ inside it")
    spec = TrialSpec(config=str(args.config.resolve()), controller=name, cohort=str(args.cohort.resolve()),
                     patients=args.patients, sessions=args.sessions, duration_s=args.duration, seed=args.seed,
                     out=str(args.out.resolve()), twin=args.twin, scheduler=args.scheduler, workers=args.workers,
                     record=args.record, target_success=args.target_success)
    with _Bar(args.patients, args.target_success) as bar:
        doc = run_trial(spec, cohort, args.target_success, on_entry=bar.done)
    s = doc["summary"]
    print(f"{s['met']} of {s['patients']} patients met the target (success of the moves the rig drives >= "
          f"{args.target_success:.0%}, no safety event): {s['met_share']:.0%}; errors {s['errors']}, with safety "
          f"events {s['with_safety_events']}; {doc['trial']['wall_s']:.0f} s on {doc['trial']['backend']}")
    for stratum, g in s["strata"].items():
        print(f"  {stratum}: {g['met']} of {g['patients']}, median success (driven) "
              f"{_pct(g['median_success_assisted'])}, median assistance ratio (last cycle) "
              f"{_g(g['median_assistance_ratio_last'])}")
    print(f"wrote {args.out / 'trial.json'} and {args.out / TRIAL_PAGE}")
    return 0


def _pct(v: float | None) -> str:
    return "–" if v is None or not math.isfinite(v) else f"{v:.0%}"


def _g(v: float | None) -> str:
    return "–" if v is None or not math.isfinite(v) else f"{v:.2f}"


def _check_scheduler(address: str) -> None:
    """The scheduler answers, or one line (before any patient is drawn into a task)."""
    try:
        from distributed import Client
    except ImportError:
        raise UserError("--scheduler: the 'distributed' package is not installed (pip install distributed)") from None
    try:
        with Client(address, timeout="10s") as client:
            n = len(client.scheduler_info().get("workers", {}))
    except (OSError, TimeoutError, ValueError) as e:
        raise UserError(f"--scheduler {address}: no Dask scheduler answers there: {e}") from None
    if n == 0:
        print(f"rehab-hil trial: the scheduler at {address} has no worker yet; the patients wait for one",
              file=sys.stderr)


class _Bar:
    """The progress bar (rich, on standard error): patients done, the errors and the targets missed so
    far, the time left. Not on a terminal: one line per patient instead."""

    def __init__(self, total: int, target: float) -> None:
        from rich.console import Console
        from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeRemainingColumn

        self.console = Console(stderr=True)
        self.live = self.console.is_terminal
        self.progress = Progress(TextColumn("[bold]trial[/]"), BarColumn(), MofNCompleteColumn(),
                                 TextColumn("{task.description}"), TimeRemainingColumn(), console=self.console,
                                 disable=not self.live)
        self.task = self.progress.add_task("", total=total)
        self.total, self.target, self.n, self.errors, self.missed = total, target, 0, 0, 0

    def __enter__(self) -> _Bar:
        self.progress.start()
        return self

    def __exit__(self, *exc: Any) -> None:
        self.progress.stop()

    def done(self, entry: dict[str, Any]) -> None:
        from rehab_hil.trial.results import last_session, meets_target

        self.n += 1
        self.errors += bool(entry.get("error"))
        self.missed += not meets_target(entry, self.target)
        text = f"missed {self.missed}, errors {self.errors}"
        self.progress.update(self.task, advance=1, description=text)
        if not self.live:
            last = last_session(entry) or {}
            v = last.get("success_assisted")
            what = (f"error: {entry['error']['type']}: {entry['error']['message']}" if entry.get("error")
                    else f"success (driven) {_pct(v)}")
            print(f"rehab-hil trial: {self.n}/{self.total} {entry['id']} ({entry['stratum']}): {what}",
                  file=sys.stderr, flush=True)
