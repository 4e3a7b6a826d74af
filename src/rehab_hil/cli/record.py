"""``rehab-hil record --from-zenoh RIG --out DIR``: write a rig's zenoh telemetry as run.csv + run.mcap,
the same files a local ``run --record`` writes (docs/telemetry.md)."""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

from rehab_hil.cli import UserError
from rehab_hil.plants import get_plant, load_config
from rehab_hil.telemetry.cliargs import add_network_args, network_from_args
from rehab_hil.telemetry.keys import RigIdError, validate_rig_id
from rehab_hil.telemetry.session import TelemetryConfigError, open_session
from rehab_hil.telemetry.subscriber import query_info
from rehab_hil.telemetry.zrecord import ZenohRecorder


def add_parser(sub: argparse._SubParsersAction) -> argparse.ArgumentParser:
    p = sub.add_parser("record", help="record a rig's telemetry from zenoh to CSV + MCAP")
    p.add_argument("--from-zenoh", required=True, metavar="RIG", help="rig id to record")
    p.add_argument("--out", required=True, type=Path, help="directory for run.csv and run.mcap")
    p.add_argument("--name", default="run", help="file name stem (default: run)")
    p.add_argument("--config", type=Path, default=None,
                   help="plant config (default: the one the rig reports in rehab/<rig>/info)")
    p.add_argument("--duration", type=float, default=None, help="stop after this many seconds (default: until "
                   "the rig stops)")
    p.add_argument("--wait", type=float, default=10.0,
                   help="how long to wait for the hub and the rig to appear [s] (default 10)")
    add_network_args(p)
    return p


def _binding(args: argparse.Namespace, info: dict | None):  # type: ignore[no-untyped-def]
    if args.config is not None:
        cfg = load_config(args.config)
    else:
        text = (info or {}).get("config_toml")
        if not text:
            raise UserError(f"rig {args.from_zenoh!r} did not report its config; pass --config")
        with tempfile.TemporaryDirectory() as d:
            path = Path(d) / "rig_config.toml"
            path.write_text(text, encoding="utf-8")
            cfg = load_config(path)
    spec = get_plant(cfg.plant)
    if spec.device is None:
        raise UserError(f"plant {spec.name!r} has no device binding")
    return spec.device(cfg)


def run(args: argparse.Namespace) -> int:
    try:
        rig = validate_rig_id(args.from_zenoh)
        net = network_from_args(args)
    except (RigIdError, TelemetryConfigError) as e:
        raise UserError(str(e)) from None
    if args.duration is not None and not 0 < args.duration <= 24 * 3600:
        raise UserError(f"--duration must be in (0, 86400] s, got {args.duration}")
    if not 0 <= args.wait <= 3600:
        raise UserError(f"--wait must be in [0, 3600] s, got {args.wait}")
    end_wait = time.monotonic() + args.wait
    while True:  # the rig (hosting the loopback hub) may start after the recorder
        try:
            session = open_session(net)
            break
        except TelemetryConfigError as e:
            if time.monotonic() >= end_wait:
                raise UserError(str(e)) from None
            time.sleep(0.25)
    try:
        info = None
        while info is None and time.monotonic() < end_wait:
            info = query_info(session, rig, timeout_s=min(1.0, max(0.1, end_wait - time.monotonic())))
        if info is None and args.config is None:
            raise UserError(f"rig {rig!r} did not answer on rehab/{rig}/info within {args.wait} s")
        binding = _binding(args, info)
        with ZenohRecorder(session, rig, args.out, binding, name=args.name) as zrec:
            print(f"recording rig {rig} into {zrec.recorder.csv_path} and {zrec.recorder.mcap_path}")
            end = time.monotonic() + args.duration if args.duration else float("inf")
            try:
                while time.monotonic() < end and not zrec.done.is_set():
                    time.sleep(0.05)
            except KeyboardInterrupt:
                pass
            time.sleep(0.2)  # the last batches behind the liveliness change
        why = "rig stopped" if zrec.done.is_set() else "duration reached"
        sub = zrec.subscription
        print(f"{why}: {zrec.samples} records, {zrec.recorder.rows} CSV rows; lost: {sub.missing_batches} batches "
              f"in transit, {sub.publisher_dropped} samples at the publisher, {zrec.recorder.dropped} in the writer")
    finally:
        session.close()
    return 0
