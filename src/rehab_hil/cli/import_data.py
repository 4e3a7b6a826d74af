"""``rehab-hil import``: a lab logger's .mat or CSV file into an interchange CSV, through a mapping."""

from __future__ import annotations

import argparse
from pathlib import Path

from rehab_hil.cli import config_file


def add_parser(sub: argparse._SubParsersAction) -> argparse.ArgumentParser:
    p = sub.add_parser("import", help="convert a .mat or CSV logger file into an interchange CSV (a mapping "
                                      "says which variable is which model signal)")
    p.add_argument("--data", required=True, type=Path, help="the logger's file (.mat, or CSV with a header row)")
    src = p.add_mutually_exclusive_group(required=True)
    src.add_argument("--mapping", type=Path, help="TOML file with an [import] table (time or sample_time_s, "
                                                  "[import.signals.<signal>] variable, unit, scale, offset)")
    src.add_argument("--config", type=config_file, help="a plant config whose [import] table is the mapping")
    p.add_argument("--out", required=True, type=Path, help="interchange CSV to write")
    return p


def run(args: argparse.Namespace) -> int:
    from rehab_hil.importing import load_mapping, read_mapped
    from rehab_hil.interchange import write_csv

    source = args.mapping or args.config
    mapping = load_mapping(source)
    rec = read_mapped(args.data, mapping, source)
    if args.config is not None:  # the signals must be the plant's: check them before writing
        from rehab_hil.cli import UserError
        from rehab_hil.loading import load_config
        from rehab_hil.plants import get_plant

        cfg = load_config(args.config)
        spec = get_plant(cfg.plant)
        known = {*spec.input_signals(cfg), *spec.inputs, *spec.outputs, *spec.optional_inputs}
        rc = getattr(cfg, "recorded_controller", None)
        if rc is not None:
            known |= {rc.reference, rc.effort, *rc.disturbances}
        unknown = sorted(set(rec.signals) - known)
        if unknown:
            raise UserError(f"{args.config}: import.signals: {unknown} are not signals of plant {spec.name!r} "
                            f"(its signals: {sorted(known)})")
    write_csv(args.out, rec.t, rec.signals)
    dt = float(rec.t[1] - rec.t[0]) if rec.t.size > 1 else float("nan")
    print(f"wrote {args.out}: {rec.t.size} rows over {rec.t[-1]:.3f} s (first step {dt * 1e3:.3g} ms), "
          f"columns {', '.join(rec.signals)}")
    return 0
