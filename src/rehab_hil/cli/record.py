"""``rehab-hil record --from-zenoh 'RIG_PATTERN' --out ROOT``: record every matching rig from zenoh, one
run directory each (``ROOT/<UTC start>-<rig>/``: run.csv, run.mcap, metadata.json), the same files a
local ``run --record`` writes (docs/telemetry.md)."""

from __future__ import annotations

import argparse
import time
from pathlib import Path

from rehab_hil.cli import UserError, config_file
from rehab_hil.telemetry.cliargs import add_network_args, network_from_args
from rehab_hil.telemetry.lab import LabError, LabRecorder, rig_matcher
from rehab_hil.telemetry.session import TelemetryConfigError, open_session
from rehab_hil.telemetry.subscriber import list_rigs


def add_parser(sub: argparse._SubParsersAction) -> argparse.ArgumentParser:
    p = sub.add_parser("record", help="record rigs' telemetry from zenoh to CSV + MCAP, one run directory per rig")
    p.add_argument("--from-zenoh", required=True, metavar="RIG_PATTERN",
                   help="rig id or shell-style pattern (quote it), e.g. bench1, 'bench*', 'lab-?'")
    p.add_argument("--out", required=True, type=Path, help="root directory for the run directories")
    p.add_argument("--config", type=config_file, default=None,
                   help="plant config (default: the one each rig reports in rehab/<rig>/info)")
    p.add_argument("--duration", type=float, default=None, help="stop after this many seconds (default: when "
                   "every recorded rig has stopped)")
    p.add_argument("--wait", type=float, default=10.0,
                   help="how long to wait for the hub and a matching rig to appear [s] (default 10)")
    p.add_argument("--no-history", dest="history", action="store_false",
                   help="record from the moment of subscribing, without the rig publisher's history")
    p.add_argument("--recover", action="store_true",
                   help="ask the rig publisher's cache for batches missed in transit (a late start may then lose "
                   "the history: docs/telemetry.md)")
    add_network_args(p)
    return p


def run(args: argparse.Namespace) -> int:
    try:
        rig_matcher(args.from_zenoh)
        net = network_from_args(args)
    except (LabError, TelemetryConfigError) as e:
        raise UserError(str(e)) from None
    if args.duration is not None and not 0 < args.duration <= 24 * 3600:
        raise UserError(f"--duration must be in (0, 86400] s, got {args.duration}")
    if not 0 <= args.wait <= 3600:
        raise UserError(f"--wait must be in [0, 3600] s, got {args.wait}")
    end_wait = time.monotonic() + args.wait
    try:  # a rig hosting the loopback hub may start after the recorder: wait for it
        session = open_session(net, wait_s=args.wait)
    except TelemetryConfigError as e:
        raise UserError(str(e)) from None
    lab = None
    try:
        lab = LabRecorder(session, args.from_zenoh, args.out, config=args.config, history=args.history,
                          recovery=args.recover)
        started = False
        end = None
        try:
            while True:
                for line in lab.poll():
                    print(line, flush=True)
                if lab.runs and not started:
                    started = True
                    end = time.monotonic() + args.duration if args.duration else None
                if not started and time.monotonic() >= end_wait:
                    live = ", ".join(list_rigs(session, timeout_s=0.5)) or "none"
                    why = "; ".join(lab.errors) if lab.errors else f"live rigs: {live}"
                    raise UserError(f"no live rig matches {args.from_zenoh!r} within {args.wait} s ({why})")
                if started and not lab.runs:
                    break  # every recorded rig has stopped
                if end is not None and time.monotonic() >= end:
                    break
                time.sleep(0.05)
        except KeyboardInterrupt:
            pass
        for line in lab.close():
            print(line, flush=True)
        lab = None
    finally:
        if lab is not None:
            lab.close("error")
        session.close()
    return 0
