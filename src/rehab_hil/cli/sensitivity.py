"""``rehab-hil sensitivity``: parameter sensitivity of the TCP finger (seed 001 sec 5.2, Fig. 11-12)."""

from __future__ import annotations

import argparse

from rehab_hil.cli import UserError, config_file
from rehab_hil.loading import load_config


def add_parser(sub: argparse._SubParsersAction) -> argparse.ArgumentParser:
    p = sub.add_parser("sensitivity", help="mass/inertia/damping/K x2 and x0.5: joint-angle MSE vs nominal")
    p.add_argument("--config", required=True, type=config_file, help="a tcp_finger config (configs/tcp_finger.toml)")
    p.add_argument("--power-w", type=float, default=None, help="pulse power [W] (default: from the config)")
    return p


def run(args: argparse.Namespace) -> int:
    from rehab_hil.plants import tcp_finger

    cfg = load_config(args.config)
    if cfg.plant != "tcp_finger":
        raise UserError(f"{args.config}: sensitivity analysis is defined for plant 'tcp_finger', not {cfg.plant!r}")
    if args.power_w is not None and not (0 < args.power_w <= 200):
        raise UserError(f"--power-w must be in (0, 200] W, got {args.power_w}")
    rows = tcp_finger.sensitivity(cfg, power_w=args.power_w)
    power = cfg.sensitivity.power_w if args.power_w is None else args.power_w
    print(f"tcp_finger sensitivity, PIS pulse at {power:g} W: MSE [deg^2] of each joint angle vs nominal")
    print(tcp_finger.sensitivity_table(rows))
    return 0
