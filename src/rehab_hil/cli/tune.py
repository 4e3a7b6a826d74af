"""``rehab-hil tune``: design a controller's settings on the (augmented) model and write them as a config.

The search runs the controller with its plant model, the config's ``[[effects]]`` included
(``controllers/tuning.py``), prints the predicted session figures before and after (and, where
the plant has a linear model, the feedback loop's margins from python-control), and writes a
copy of the config with the new ``[controllers.<name>]`` values, which every command loads.
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

from rehab_hil.cli import UserError, config_file
from rehab_hil.loading import load_config


def add_parser(sub: argparse._SubParsersAction) -> argparse.ArgumentParser:
    p = sub.add_parser("tune", help="design a controller's settings on the model and write them as a config")
    p.add_argument("--config", required=True, type=config_file,
                   help="plant config (configs/*.toml, or an augmented.toml)")
    p.add_argument("--controller", default=None, metavar="NAME",
                   help="the controller to tune (default: [rig.session] controller)")
    p.add_argument("--out", required=True, type=Path, help="the config to write (the input with the tuned table)")
    p.add_argument("--cycles", type=int, default=3, help="open-close cycles each candidate runs on the model")
    p.add_argument("--passes", type=int, default=2, help="coordinate-search passes over the settings")
    return p


def run(args: argparse.Namespace) -> int:
    from rehab_hil.controllers.tuning import feedback_margins, settings_table, tune, write_settings

    cfg = load_config(args.config)
    if args.out.is_dir():
        raise UserError(f"--out {args.out} is a directory; give the config file to write")
    if args.out.resolve() == args.config.resolve():
        raise UserError("--out is the input config: write the tuned config to a new file")
    if not 1 <= args.cycles <= 20 or not 1 <= args.passes <= 5:
        raise UserError("--cycles must be in 1..20 and --passes in 1..5")
    name = args.controller or (cfg.rig.session.controller if cfg.rig.session else None)
    if name is None:
        raise UserError(f"{args.config} has no [rig.session]; name the controller with --controller")
    t0 = time.perf_counter()
    print(f"tuning [controllers.{name}] of {args.config} on its model ({args.cycles} cycles per candidate) ...")
    result = tune(cfg, name, str(args.config), args.cycles, args.passes, progress=lambda s: print(f"  {s}"))
    print(f"{result.evaluations} closed-loop runs in {time.perf_counter() - t0:.0f} s")
    print(f"{'predicted per cycle':28s} {'before':>10s} {'after':>10s}")
    for k in ("rmse_deg", "max_error_deg", "rom_deg", "time_to_open_s", "time_to_closed_s", "peak_temperature_c",
              "energy_per_cycle_j"):
        print(f"{k:28s} {result.figures_before[k]:10.4g} {result.figures_after[k]:10.4g}")
    for line in settings_table(result.before, result.after) or ["no setting changed: the config's are the best found"]:
        print(f"  {line}")
    tuned = cfg.controllers[name].model_validate(result.after)
    margins = feedback_margins(cfg, tuned) if {"kp_per_deg", "ki_per_deg_s"} <= set(result.after) else None
    if margins:
        print("feedback loop on the linear model: " + ", ".join(f"{k} {v:.3g}" for k, v in margins.items()))
    try:
        changed = {k: v for k, v in result.after.items() if result.before.get(k) != v}
        args.out.write_text(write_settings(args.config.read_text(), name, changed))
    except OSError as e:
        raise UserError(f"--out {args.out}: {e.strerror}") from None
    load_config(args.out)  # the written config loads, or this is a bug worth seeing
    print(f"wrote {args.out}")
    return 0
