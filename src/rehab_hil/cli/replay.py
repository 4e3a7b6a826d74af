"""``rehab-hil replay``: drive a config's model with a recording's measured inputs and say how well
its outputs match: the last step of the model loop (does ``augmented.toml`` fit the rig better?)."""

from __future__ import annotations

import argparse
from pathlib import Path

from rehab_hil.cli import config_file


def add_parser(sub: argparse._SubParsersAction) -> argparse.ArgumentParser:
    p = sub.add_parser("replay", help="replay a recording's inputs through a config's model; per-channel errors")
    p.add_argument("--config", required=True, type=config_file, help="plant config, e.g. a report's augmented.toml")
    p.add_argument("--data", required=True, type=Path,
                   help="a run directory of `rehab-hil run --record`, its run.csv or run.mcap, or an interchange CSV")
    p.add_argument("--out", type=Path, default=None, help="write the model's outputs (interchange CSV)")
    return p


def run(args: argparse.Namespace) -> int:
    import numpy as np

    from rehab_hil.cli.data_path import load_checked, resolve_data
    from rehab_hil.discrepancy.records import GAP_MEASURE, whole_record
    from rehab_hil.discrepancy.replay import Replay, channel_metrics
    from rehab_hil.interchange import write_csv
    from rehab_hil.loading import load_config
    from rehab_hil.plants import get_plant

    cfg = load_config(args.config)
    plant = get_plant(cfg.plant)
    loaded = load_checked(resolve_data(args.data, "replay"), plant, cfg, "replay", "compared without it")
    replay = Replay.build(plant, cfg, loaded.recording, loaded.source)
    model = whole_record(replay, replay.nominal_params())
    effects = ", ".join(e.name for e in getattr(cfg, "effects", ())) or "none"
    print(f"{cfg.plant} model of {args.config} (effects: {effects}) on {loaded.source} "
          f"({replay.t.size} samples, {replay.t[-1]:.2f} s; {GAP_MEASURE}, as `discrepancy` gives the gap)")
    for c in replay.channels:
        m = channel_metrics(replay.measured[c], model[c])
        print(f"  {c:24s} RMSE {m['rmse']:.4g}  MAE {m['mae']:.4g}  max {m['max_abs_error']:.4g}")
    if args.out:
        write_csv(args.out, replay.t, {c: np.asarray(model[c]) for c in replay.channels})
        print(f"wrote {args.out}")
    return 0
