"""``rehab-hil identify``: fit continuous transfer functions of orders 1-3 to a recorded CSV and
print a seed 001 Table 1-style fit table (fit %, MSE, AIC, recommended order)."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from rehab_hil.cli import UserError
from rehab_hil.cli.data_path import resolve_data
from rehab_hil.identification import IdentificationError, compare_orders, format_table
from rehab_hil.rig_recording import read_recording


def parse_range(text: str, what: str, lo: int, hi: int) -> list[int]:
    """``"1-3"`` or ``"1,3"`` or ``"2"`` -> sorted integers, each within [lo, hi]."""
    out: set[int] = set()
    try:
        for part in text.split(","):
            a, _, b = part.strip().partition("-")
            first, last = int(a), int(b or a)
            if first > last:
                raise ValueError
            out.update(range(first, last + 1))
    except ValueError:
        raise UserError(f"{what} must look like 1-3 or 1,2, got {text!r}") from None
    if not out or min(out) < lo or max(out) > hi:
        raise UserError(f"{what} must lie in {lo}..{hi}, got {text!r}")
    return sorted(out)


def add_parser(sub: argparse._SubParsersAction) -> argparse.ArgumentParser:
    p = sub.add_parser("identify", help="fit transfer functions (orders 1-3) to an input/output CSV record")
    p.add_argument("--data", required=True, type=Path,
                   help="interchange CSV (time_s + signal columns), or a run directory or run.mcap "
                        "of `rehab-hil run --record`")
    p.add_argument("--input", required=True, help="input column, e.g. power_w")
    p.add_argument("--output", required=True, help="output column, e.g. tcp_temperature_c")
    p.add_argument("--orders", default="1-3", help="numbers of poles to try, e.g. 1-3 (default)")
    p.add_argument("--zeros", default=None, help="numbers of zeros to try (default: 0..order for each order)")
    return p


def run(args: argparse.Namespace) -> int:
    orders = parse_range(args.orders, "--orders", 1, 6)
    zeros = None if args.zeros is None else parse_range(args.zeros, "--zeros", 0, 6)
    loaded = read_recording(resolve_data(args.data, "identify"))
    for note in loaded.notes:
        print(f"rehab-hil identify: warning: {note}", file=sys.stderr)
    rec = loaded.recording
    rec.require([args.input, args.output], loaded.source)
    try:
        results = compare_orders(rec.t, rec[args.input], rec[args.output], orders, zeros)
    except IdentificationError as e:
        raise UserError(f"{args.data}: {e}") from None
    print(format_table(results, args.input, args.output))
    return 0
