"""``rehab-hil discrepancy``: name the effect missing from a model, fit it, and report the gap."""

from __future__ import annotations

import argparse
import contextlib
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
    p.add_argument("--data", required=True, type=Path, action="append",
                   help="measured data: a run directory of `rehab-hil run --record`, its run.csv or run.mcap, "
                        "or an interchange CSV; repeat it to fit one parameter set over several records (each "
                        "from its own start state, effects chosen as a set)")
    p.add_argument("--out", required=True, type=Path, help="report directory to write")
    p.add_argument("--max-effects", type=int, default=None,
                   help="most terms named: rounds of the search (default 2), or the largest set compared (default 3)")
    p.add_argument("--search", choices=("auto", "sets", "rounds"), default="auto",
                   help="how effects are chosen: as a set (several records: the default) or in rounds, one "
                        "at a time (one record: the default); docs/discrepancy.md")
    p.add_argument("--holdout", type=float, default=0.4, help="final share of the record held out (default 0.4)")
    p.add_argument("--start", choices=("auto", "rest", "estimate"), default="auto",
                   help="each record's start state (with several records, judged per record): rest (the config's "
                        "rest, measured states from the first "
                        "sample), estimate (unmeasured states fitted on the first 1.5 s), or auto (default: as "
                        "estimate, but a record whose channels do not move in the first 50 ms keeps its start "
                        "velocities at 0 when the fitted ones would show)")
    p.add_argument("--validate", type=Path, action="append", default=[], metavar="DATA",
                   help="another record of the same plant: the nominal and the augmented model are scored on it "
                        "(fit on --data, validate on DATA), and a term that makes the validation records worse "
                        "than its given value is rejected, not reported as a finding (without --validate, the "
                        "records' held-out parts judge); may be repeated")
    return p


def run(args: argparse.Namespace) -> int:
    from rich.console import Console
    from rich.progress import BarColumn, MofNCompleteColumn, Progress, SpinnerColumn, TextColumn, TimeElapsedColumn

    from rehab_hil.cli import UserError, writable_folder
    from rehab_hil.discrepancy.report import write_report
    from rehab_hil.discrepancy.workflow import find_missing_effects
    from rehab_hil.outputs import staged_folder
    from rehab_hil.report.discrepancy import discrepancy_page

    if args.max_effects is not None and not 1 <= args.max_effects <= 5:
        raise UserError(f"--max-effects must be 1..5, got {args.max_effects}")
    if not 0.1 <= args.holdout <= 0.9:
        raise UserError(f"--holdout must be in [0.1, 0.9], got {args.holdout}")
    # check the inputs before the progress display starts, so a user error prints one line only
    cfg, recs, sources, val_recs = _load_records(args)
    out = Path(args.out)
    made = not out.exists()
    writable_folder(out, "--out", "the report is several files")  # before the fit: nothing lost
    console = Console(stderr=True)
    cols = (SpinnerColumn(), TextColumn("{task.description}"), BarColumn(), MofNCompleteColumn(),
            TextColumn("simulations"), TimeElapsedColumn())
    try:
        with Progress(*cols, console=console, transient=False) as bar:
            progress = RichProgress(bar)
            sets = args.search == "sets" or (args.search == "auto" and len(recs) > 1)
            opts = Options(holdout_fraction=args.holdout, max_effects=args.max_effects or (3 if sets else 2),
                           search=args.search, start=args.start)
            res = find_missing_effects(cfg, recs if len(recs) > 1 else recs[0],
                                       sources if len(recs) > 1 else sources[0], progress, opts,
                                       list(zip(val_recs, args.validate, strict=True)))
            _validate(res, cfg, val_recs, args.validate, progress)
            progress.start("writing report", None)
            with staged_folder(out) as tmp:  # every file, or none: Ctrl-C never leaves a folder with one plot
                rep = write_report(res, Path(args.config), ", ".join(str(d) for d in args.data), tmp)
                discrepancy_page(res, rep).write(tmp / "report.html")
    except BaseException:
        if made:  # the folder made for the report goes again, unless something else was put in it
            with contextlib.suppress(OSError):
                out.rmdir()
        raise
    _print_summary(res, args.out)
    return 0


def _validate(res: Result, cfg: Any, val_recs: list[Recording], paths: list[Path], progress: Any) -> None:
    """Score the models on each validation record; the first is the report's validation, every one is
    a row of the gap table (the same measure as the estimation records')."""
    from rehab_hil.discrepancy.validation import validate

    for i, (rec, path) in enumerate(zip(val_recs, paths, strict=True)):
        progress.start(f"validating on {path}", None)
        v = validate(res, cfg, rec, path)
        if i == 0:
            res.validation = v
        res.gaps.setdefault("validation", []).append({"data": str(path), "nominal": v.nominal,
                                                      "augmented": v.augmented})


def _load_records(args: argparse.Namespace) -> tuple[Any, list[Recording], list[Path], list[Recording]]:
    """The config, the records (``args.data`` resolved in place), their source names and the validation
    records, each checked replayable; warnings on stderr."""
    from rehab_hil.cli.data_path import load_checked, resolve_data
    from rehab_hil.loading import load_config
    from rehab_hil.plants import get_plant

    cfg = load_config(args.config)
    plant = get_plant(cfg.plant)
    args.data = [resolve_data(Path(d), "discrepancy") for d in args.data]
    loaded = [load_checked(d, plant, cfg, "discrepancy", "the analysis runs without it") for d in args.data]
    recs, sources = [x.recording for x in loaded], [x.source for x in loaded]
    val_recs = [load_checked(v, plant, cfg, "discrepancy").recording for v in args.validate]
    return cfg, recs, sources, val_recs


def gap_lines(gaps: dict[str, Any]) -> list[str]:
    """The gap per record, estimation and validation, and overall (the root mean square over the
    records), each channel's RMSE nominal -> augmented, in the one measure the gaps say."""
    if not gaps:
        return []
    out = [f"  RMSE per record ({gaps['measure']}):"]
    rows = [("estimation", g) for g in gaps["records"]] + [("validation", g) for g in gaps.get("validation", [])]
    for role, g in rows:
        for c, m in g["nominal"].items():
            after = g["augmented"][c]["rmse"]
            out.append(f"    {role:10s} {Path(g['data']).name:24s} {c:14s} {m['rmse']:.4g} -> {after:.4g}")
    for role in ("estimation", "validation"):
        sel = [g for r, g in rows if r == role]
        if len(sel) > 1:
            for c in sel[0]["nominal"]:
                b = (sum(g["nominal"][c]["rmse"] ** 2 for g in sel) / len(sel)) ** 0.5
                a = (sum(g["augmented"][c]["rmse"] ** 2 for g in sel) / len(sel)) ** 0.5
                out.append(f"    {role:10s} {'overall':24s} {c:14s} {b:.4g} -> {a:.4g}")
    return out


def _print_summary(res: Result, out: Path) -> None:
    """The conclusion, the fitted terms, each channel's RMSE before and after, and the validation."""
    from rehab_hil.discrepancy.report import effect_params_text
    from rehab_hil.discrepancy.result import parameter_sentence
    from rehab_hil.discrepancy.verdict import channel_unit
    from rehab_hil.discrepancy.wording import is_linear, param_unit

    print(f"{res.plant}: {res.conclusion} ({res.wall_s:.1f} s)")
    linear = is_linear(res.extras.get("replay"))
    for f in res.chosen:
        if f.kind != "effect":
            print("  " + parameter_sentence(f))
            continue
        units = {k: param_unit(k, linear) for k in f.params}
        print("  " + f.effect + ": " + effect_params_text({"params": f.params, "stderr": f.stderr, "units": units}))
    lines = gap_lines(res.gaps)
    if not lines:
        before, after = res.metrics("nominal"), res.metrics("augmented")
        lines = [f"  RMSE nominal -> augmented ({res.measure}):"] + [
            f"  {c:24s} {before[c]['rmse']:.4g} -> {after[c]['rmse']:.4g} {channel_unit(c)}" for c in res.channels]
    for line in lines + (res.validation.lines() if res.validation is not None else []):
        print(line)
    for g in res.gaps.get("records", []) if len(res.gaps.get("records", [])) > 1 else []:
        if "start" in g:
            print(f"  start of {Path(g['data']).name}: " + ("; ".join(g["start"]["summary"]) or "the config's rest"))
    if res.lacking:
        print("  the records lack: " + "; ".join(res.lacking))
    print(f"wrote {out}/report.json, report.md, report.html, *.png, augmented.toml")
