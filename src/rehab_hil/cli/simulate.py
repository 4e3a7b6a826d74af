"""``rehab-hil simulate``: run a plant scenario offline, write the interchange CSV, print metrics."""

from __future__ import annotations

import argparse
import time
from pathlib import Path

from rehab_hil.cli import UserError
from rehab_hil.config import load_config
from rehab_hil.interchange import write_csv
from rehab_hil.plants import get_plant
from rehab_hil.plants.base import run_scenario


def add_parser(sub: argparse._SubParsersAction) -> argparse.ArgumentParser:
    p = sub.add_parser("simulate", help="simulate a plant scenario and write the interchange CSV")
    p.add_argument("--config", required=True, type=Path, help="plant config (configs/*.toml)")
    p.add_argument("--scenario", required=True, help="scenario name (plant-specific, e.g. step, cycle)")
    p.add_argument("--duration", type=float, default=None, help="duration [s] (default: from the config)")
    p.add_argument("--out", type=Path, default=None, help="CSV to write")
    return p


def run(args: argparse.Namespace) -> int:
    cfg = load_config(args.config)
    spec = get_plant(cfg.plant)
    if args.scenario not in spec.scenarios:
        raise UserError(f"plant {spec.name!r} has no scenario {args.scenario!r}; choose from {sorted(spec.scenarios)}")
    if args.duration is not None and not (0 < args.duration <= 24 * 3600):
        raise UserError(f"--duration must be in (0, 86400] s, got {args.duration}")
    scenario = spec.scenarios[args.scenario](cfg, duration_s=args.duration)
    t0 = time.perf_counter()
    res = run_scenario(spec, cfg, scenario)
    wall = time.perf_counter() - t0
    sim_s = scenario.n_steps * spec.step(cfg)[0]
    print(f"{spec.name} / {scenario.name}: {scenario.n_steps} steps, {sim_s:.3f} s simulated in {wall:.3f} s wall")
    if scenario.metrics:
        for k, v in scenario.metrics(res).items():
            print(f"  {k:24s} {v:12.4f}")
    if args.out:
        write_csv(args.out, res.t, res.signals)
        print(f"wrote {args.out} ({len(res.t)} rows, columns: time_s, {', '.join(res.signals)})")
    return 0
