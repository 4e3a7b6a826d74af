"""Command-line options shared by every telemetry command (``run --telemetry``, ``monitor``, ``record``).

Passwords come from a file or ``REHAB_ZENOH_PASSWORD``, never from the command line (visible in ps).
"""

from __future__ import annotations

import argparse
import os
from pathlib import Path

from rehab_hil.telemetry.session import DEFAULT_PORT, NetworkConfig, TelemetryConfigError

__all__ = ["PASSWORD_ENV", "add_network_args", "network_from_args"]

PASSWORD_ENV = "REHAB_ZENOH_PASSWORD"


def add_network_args(p: argparse.ArgumentParser) -> None:
    """Add --port, --connect, --user, --password-file and the TLS file options to ``p``."""
    g = p.add_argument_group("zenoh network (default: loopback 127.0.0.1 only; docs/telemetry.md)")
    g.add_argument("--port", type=int, default=DEFAULT_PORT, help=f"loopback hub port (default {DEFAULT_PORT})")
    g.add_argument("--connect", action="append", default=None, metavar="ENDPOINT",
                   help="lab mode: zenoh router endpoint, e.g. tcp/10.0.0.2:7447 or tls/router:7447 (repeatable)")
    g.add_argument("--user", default=None, help="zenoh user name (user/password authentication)")
    g.add_argument("--password-file", type=Path, default=None,
                   help=f"file holding the password (or set {PASSWORD_ENV})")
    g.add_argument("--tls-ca", type=Path, default=None,
                   help="TLS root CA certificate (PEM); without --connect: the loopback hub over TLS")
    g.add_argument("--tls-cert", type=Path, default=None, help="TLS client certificate (PEM), for mutual TLS")
    g.add_argument("--tls-key", type=Path, default=None, help="TLS client private key (PEM)")


def network_from_args(args: argparse.Namespace) -> NetworkConfig:
    """The client ``NetworkConfig`` the options describe; bad combinations raise ``TelemetryConfigError``."""
    password = None
    if args.password_file is not None:
        try:
            password = args.password_file.read_text(encoding="utf-8").strip()
        except OSError as e:
            raise TelemetryConfigError(f"--password-file {args.password_file}: {e.strerror}") from None
    elif args.user is not None:
        password = os.environ.get(PASSWORD_ENV)
        if password is None:
            raise TelemetryConfigError(f"--user needs --password-file or the {PASSWORD_ENV} environment variable")
    elif args.password_file is None and os.environ.get(PASSWORD_ENV) and args.user is None:
        password = None  # a password without a user is ignored, as zenoh would
    net = NetworkConfig(
        mode="lab" if args.connect else "loopback", role="client", port=args.port,
        tls=args.tls_ca is not None and not args.connect,  # loopback hub over TLS when a CA is given
        router=tuple(args.connect or ()), user=args.user, password=password,
        tls_root_ca=args.tls_ca, tls_certificate=args.tls_cert, tls_private_key=args.tls_key,
    )
    return net.validate()
