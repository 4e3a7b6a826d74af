"""``rehab-hil discrepancy``: name the effect missing from a model, fit it, and report the gap."""

from __future__ import annotations

import argparse
import contextlib
import sys
from pathlib import Path
from typing import TYPE_CHECKING, Any

from rehab_hil.cli import config_file
from rehab_hil.discrepancy.workflow import Options, Progress

if TYPE_CHECKING:
    from rehab_hil.discrepancy.result import Result
    from rehab_hil.interchange import Recording


class RichProgress(Progress):
    """Shows each fitting stage and the simulations it has run."""

    def __init__(self, progress: Any) -> None:  # a rich.progress.Progress
        self.p = progress
        self.task = None

    def start(self, label: str, total: int | None = None) -> None:
        if self.task is not None:
            self.p.update(self.task, completed=self.p.tasks[-1].completed, total=self.p.tasks[-1].completed)
        self.task = self.p.add_task(label, total=total)

    def advance(self) -> None:
        if self.task is not None:
            self.p.advance(self.task)


def add_parser(sub: argparse._SubParsersAction) -> argparse.ArgumentParser:
    p = sub.add_parser("discrepancy", help="find the effect missing from the model in measured data")
    p.add_argument("--config", required=True, type=config_file, help="plant config (configs/*.toml)")
    p.add_argument("--data", required=True, type=Path,
                   help="measured data: a run directory of `rehab-hil run --record`, its run.csv or run.mcap, "
                        "or an interchange CSV")
    p.add_argument("--out", required=True, type=Path, help="report directory to write")
    p.add_argument("--max-effects", type=int, default=2, help="most effects to add in turn (default 2)")
    p.add_argument("--holdout", type=float, default=0.4, help="final share of the record held out (default 0.4)")
    p.add_argument("--validate", type=Path, default=None, metavar="DATA",
                   help="another record of the same plant: the nominal and the augmented model are scored on it "
                        "(fit on --data, validate on DATA)")
    return p


def run(args: argparse.Namespace) -> int:
    from rich.console import Console
    from rich.progress import BarColumn, MofNCompleteColumn, Progress, SpinnerColumn, TextColumn, TimeElapsedColumn

    from rehab_hil.cli import UserError, writable_folder
    from rehab_hil.discrepancy.report import write_report
    from rehab_hil.discrepancy.workflow import find_missing_effects
    from rehab_hil.outputs import staged_folder
    from rehab_hil.report.discrepancy import discrepancy_page

    if not 1 <= args.max_effects <= 5:
        raise UserError(f"--max-effects must be 1..5, got {args.max_effects}")
    if not 0.1 <= args.holdout <= 0.9:
        raise UserError(f"--holdout must be in [0.1, 0.9], got {args.holdout}")
    # check the inputs before the progress display starts, so a user error prints one line only
    cfg, rec, source, val_rec = _load_records(args)
    out = Path(args.out)
    made = not out.exists()
    writable_folder(out, "--out", "the report is several files")  # before the fit: nothing lost
    console = Console(stderr=True)
    cols = (SpinnerColumn(), TextColumn("{task.description}"), BarColumn(), MofNCompleteColumn(),
            TextColumn("simulations"), TimeElapsedColumn())
    try:
        with Progress(*cols, console=console, transient=False) as bar:
            progress = RichProgress(bar)
            res = find_missing_effects(cfg, rec, source, progress,
                                       Options(holdout_fraction=args.holdout, max_effects=args.max_effects))
            if val_rec is not None:
                from rehab_hil.discrepancy.validation import validate

                progress.start("validating on the second record", None)
                res.validation = validate(res, cfg, val_rec, args.validate)
            progress.start("writing report", None)
            with staged_folder(out) as tmp:  # every file, or none: Ctrl-C never leaves a folder with one plot
                rep = write_report(res, Path(args.config), Path(args.data), tmp)
                discrepancy_page(res, rep).write(tmp / "report.html")
    except BaseException:
        if made:  # the folder made for the report goes again, unless something else was put in it
            with contextlib.suppress(OSError):
                out.rmdir()
        raise
    _print_summary(res, args.out)
    return 0


def _load_records(args: argparse.Namespace) -> tuple[Any, Recording, Path, Recording | None]:
    """The config, the record (``args.data`` resolved in place), its source name and the validation
    record (or None), each checked replayable; warnings on stderr."""
    from rehab_hil.cli.data_path import missing_channels, resolve_data
    from rehab_hil.discrepancy.replay import check_recording
    from rehab_hil.loading import load_config
    from rehab_hil.plants import get_plant
    from rehab_hil.rig_recording import load_recording

    cfg = load_config(args.config)
    plant = get_plant(cfg.plant)
    args.data = resolve_data(Path(args.data), "discrepancy")
    loaded = load_recording(args.data, plant, cfg)
    rec = loaded.recording
    for note in loaded.notes:
        print(f"rehab-hil discrepancy: warning: {note}", file=sys.stderr)
    for c in missing_channels(plant, cfg, rec.signals):
        print(f"rehab-hil discrepancy: warning: {loaded.source}: no {c!r} column (a {plant.name} output the rig "
              "records): the analysis runs without it", file=sys.stderr)
    check_recording(plant, rec, loaded.source)
    val_rec = None
    if args.validate is not None:
        val_loaded = load_recording(args.validate, plant, cfg)
        for note in val_loaded.notes:
            print(f"rehab-hil discrepancy: warning: {note}", file=sys.stderr)
        check_recording(plant, val_loaded.recording, val_loaded.source)
        val_rec = val_loaded.recording
    return cfg, rec, loaded.source, val_rec


def _print_summary(res: Result, out: Path) -> None:
    """The conclusion, the fitted terms, each channel's RMSE before and after, and the validation."""
    print(f"{res.plant}: {res.conclusion} ({res.wall_s:.1f} s)")
    for f in res.chosen:
        print("  " + f.effect + ": " + ", ".join(f"{k} = {v:.4g} ± {f.stderr[k]:.2g}" for k, v in f.params.items()))
    before, after = res.metrics("nominal"), res.metrics("augmented")
    for c in res.channels:
        print(f"  {c:24s} RMSE {before[c]['rmse']:.4g} -> {after[c]['rmse']:.4g}")
    for line in res.validation.lines() if res.validation is not None else []:
        print(line)
    print(f"wrote {out}/report.json, report.md, report.html, *.png, augmented.toml")
