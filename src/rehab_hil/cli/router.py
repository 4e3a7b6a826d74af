"""``rehab-hil router``: the lab's zenoh router (a router-mode session) listening where the lab says,
with user/password and the access-control file; rigs, monitors, recorders and Foxglove bridges
connect to it as clients (``--connect``). docs/telemetry.md, "A lab of rigs"."""

from __future__ import annotations

import argparse
import faulthandler
import json
import os
import signal
import threading
import time
from pathlib import Path
from typing import Any

from rehab_hil.cli import UserError
from rehab_hil.telemetry.session import NetworkConfig, TelemetryConfigError, open_session


def add_parser(sub: argparse._SubParsersAction) -> argparse.ArgumentParser:
    p = sub.add_parser("router", help="run the lab's zenoh router (clients: run/monitor/record/foxglove --connect)")
    p.add_argument("--listen", action="append", default=None, metavar="ENDPOINT",
                   help="endpoint to listen on, e.g. tcp/10.0.0.2:7447 (repeatable; default tcp/127.0.0.1:7447)")
    p.add_argument("--mesh", action="append", default=None, metavar="ENDPOINT",
                   help="another router of the lab to connect to (router mesh; repeatable)")
    p.add_argument("--access-control", type=Path, default=None, metavar="FILE",
                   help="JSON file with zenoh's access_control object (see telemetry.access)")
    p.add_argument("--users", type=Path, default=None, metavar="FILE",
                   help="user/password dictionary, one user:password per line")
    p.add_argument("--tls-cert", type=Path, default=None, help="TLS certificate (PEM) for tls/ endpoints")
    p.add_argument("--tls-key", type=Path, default=None, help="TLS private key (PEM)")
    p.add_argument("--tls-ca", type=Path, default=None, help="CA (PEM) that client certificates must chain to (mTLS)")
    p.add_argument("--duration", type=float, default=None, help="stop after this many seconds (default: until "
                   "Ctrl-C or SIGTERM)")
    return p


def load_access_control(path: Path) -> dict[str, Any]:
    """The ``access_control`` object from a JSON file (a top-level ``access_control`` key is unwrapped)."""
    try:
        doc = json.loads(path.read_text(encoding="utf-8"))
    except OSError as e:
        raise UserError(f"--access-control {path}: {e.strerror}") from None
    except json.JSONDecodeError as e:
        raise UserError(f"--access-control {path}: not JSON: {e}") from None
    if isinstance(doc, dict) and isinstance(doc.get("access_control"), dict):
        doc = doc["access_control"]
    if not isinstance(doc, dict) or "rules" not in doc:
        raise UserError(f"--access-control {path}: expected zenoh's access_control object (with 'rules')")
    return doc


def _cpu_s() -> float:
    t = os.times()
    return t.user + t.system


def run(args: argparse.Namespace) -> int:
    if args.duration is not None and not 0 < args.duration <= 365 * 24 * 3600:
        raise UserError(f"--duration must be positive, got {args.duration}")
    acl = load_access_control(args.access_control) if args.access_control else None
    net = NetworkConfig(mode="lab", role="hub", listen=tuple(args.listen or ["tcp/127.0.0.1:7447"]),
                        router=tuple(args.mesh or ()),
                        usrpwd_dictionary=args.users, access_control=acl, tls_root_ca=args.tls_ca,
                        tls_certificate=args.tls_cert, tls_private_key=args.tls_key)
    try:
        session = open_session(net)
    except TelemetryConfigError as e:
        raise UserError(str(e)) from None
    stop = threading.Event()
    previous = {s: signal.signal(s, lambda n, f: stop.set()) for s in (signal.SIGINT, signal.SIGTERM)}
    faulthandler.register(signal.SIGUSR1, all_threads=True)  # kill -USR1: where a router that will not stop is
    t0, cpu0 = time.monotonic(), _cpu_s()
    try:
        print(f"zenoh router listening on {', '.join(net.endpoints())}"
              f"{' meshed with ' + ', '.join(net.router) if net.router else ''}"
              f"{' with access control' if acl else ''}{' and user/password' if args.users else ''}", flush=True)
        stop.wait(args.duration)
    finally:
        for s, h in previous.items():
            signal.signal(s, h)
        session.close()
    wall, cpu = time.monotonic() - t0, _cpu_s() - cpu0
    print(f"router stopped after {wall:.1f} s; CPU {cpu:.2f} s ({100 * cpu / max(wall, 1e-9):.1f} % of one core)")
    return 0
