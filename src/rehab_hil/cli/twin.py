"""``rehab-hil twin RUN``: the live twin on a recorded session (rehab_hil.twin.offline).

The same computation as ``run --twin``, fed from the run's ``run.csv``: the residual test, the
diagnosis of each model mismatch and the patient's interaction estimate. Judge a session recorded
without the twin, or judge it again with another model (a discrepancy report's ``augmented.toml``).
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path
from typing import Any

from rehab_hil.cli import config_file


def add_parser(sub: argparse._SubParsersAction) -> argparse.ArgumentParser:
    p = sub.add_parser("twin", help="run the live twin on a recorded session: model events, causes and the "
                       "patient's interaction estimate (docs/twin.md)")
    p.add_argument("run", type=Path, metavar="RUN",
                   help="a run directory of `run --record` or its run.csv (a folder of runs: the newest)")
    p.add_argument("--config", type=config_file, default=None,
                   help="the model to judge it with (default: the config the run was made with, from its "
                        "metadata.json), e.g. a discrepancy report's augmented.toml")
    p.add_argument("--out", type=Path, default=None, metavar="DIR",
                   help="write twin.csv and twin.json (events and estimates) into DIR")
    return p


def _paths(run: Path) -> tuple[Path, Path | None]:
    """(run.csv, metadata.json or None) of a run directory or a run.csv."""
    from rehab_hil.cli import UserError
    from rehab_hil.cli.data_path import resolve_data

    if not run.exists():
        raise UserError(f"{run}: not found")
    run = resolve_data(run, "twin", flag="RUN")
    csv = run / "run.csv" if run.is_dir() else run
    if not csv.is_file():
        raise UserError(f"{run}: no run.csv (a run directory of `rehab-hil run --record`)")
    meta = csv.parent / "metadata.json"
    return csv, meta if meta.is_file() else None


def _config_path(args: argparse.Namespace, meta: Path | None) -> Path:
    from rehab_hil.cli import UserError

    if args.config is not None:
        return args.config
    if meta is None:
        raise UserError(f"{args.run}: no metadata.json saying which config made it; give --config")
    path = json.loads(meta.read_text()).get("config_path")
    if not path or not Path(path).is_file():
        raise UserError(f"{meta}: the run's config {path!r} is not here; give --config")
    return Path(path)


def run(args: argparse.Namespace) -> int:
    from rehab_hil.cli import UserError, writable_folder
    from rehab_hil.config import TwinSection
    from rehab_hil.loading import load_config
    from rehab_hil.plants.registry import get_plant
    from rehab_hil.twin.diagnosis import diagnose
    from rehab_hil.twin.live import Twin, normal_residual_text
    from rehab_hil.twin.model import TwinSetupError
    from rehab_hil.twin.offline import replay_run
    from rehab_hil.twin.session import model_event

    csv, meta = _paths(args.run)
    cfg_path = _config_path(args, meta)
    cfg = load_config(cfg_path)
    if args.out is not None:
        writable_folder(args.out, "--out", "twin.csv and twin.json go into it")
        args.out.mkdir(parents=True, exist_ok=True)
    spec = get_plant(cfg.plant)
    binding = spec.device(cfg)
    settings = cfg.twin or TwinSection()
    try:
        twin = Twin(cfg, binding, 1.0 / cfg.rig.sample_rate_hz, settings, out_dir=args.out, check_speed=False)
    except TwinSetupError as e:
        raise UserError(f"{cfg_path}: [twin] {e}") from None

    def diagnosis(ev: Any, rec: Any, x0: Any, xd0: Any) -> None:
        ev.cause = diagnose(spec, cfg, rec, x0, xd0).text

    twin.diagnose_fn = diagnosis if settings.diagnose else None
    replay_run(twin, csv)
    for ev in twin.monitor.events:
        if settings.diagnose and not ev.cause:
            ev.cause = "not diagnosed: the record ended first"
        print(f"model_mismatch {ev.text()}")
    if not twin.monitor.events:
        print(f"no model event over {twin.samples} samples (normal residual: "
              + normal_residual_text(twin.summary()["normal_residual"]) + ")")
    patient = twin.patient()
    for name, v in patient.get("session", {}).items():
        print(f"patient {name}: {v['final']:.4g} +/- {v['final_ci95']:.2g} at the end (config {v['nominal']:.4g})")
    if args.out is not None:
        out = {"run": str(csv), "config": str(cfg_path), "twin": twin.summary(),
               "model_events": [model_event(e) for e in twin.monitor.events], "patient": patient}
        (args.out / "twin.json").write_text(json.dumps(out, indent=2, default=str))
        print(f"wrote {args.out / 'twin.csv'} and {args.out / 'twin.json'}")
    return 0
