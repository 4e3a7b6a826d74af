"""``rehab-hil calibrate force``: tare, known weights up and down, fit, report, store per sensor.

PWM is locked off (CONFIGURE with ``max_duty = 0``, no COMMAND). The user is prompted to unload the
sensor (tare), then to place each weight in rising order and take them off again in falling order
(loading and unloading give the hysteresis). The fit (``rehab_hil.calibration.fit_calibration``:
linear in conductance or a low-order polynomial, chosen by residuals) is written to
``<out-dir>/<sensor-id>.toml``; reference it from the plant config (``[rig] force_calibration``).
"""

from __future__ import annotations

import argparse
import os
import statistics
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

from rich.console import Console
from rich.table import Table

from rehab_hil.calibration import G0, Calibration, CalibrationPoint, fit_calibration, write_calibration
from rehab_hil.cli import UserError, config_file, device_arg
from rehab_hil.cli.doctor import collect, firmware_configure_fallback, locked_configure
from rehab_hil.hardware import HardwareError, HardwareInterface

__all__ = ["load_steps", "measure", "weights_g"]


def weights_g(text: str) -> list[float]:
    """``"50,100,200"`` -> [50.0, 100.0, 200.0] (positive, rising)."""
    try:
        w = [float(v) for v in text.split(",") if v.strip()]
    except ValueError:
        raise UserError(f"--weights-g {text!r}: comma-separated masses in grams") from None
    if len(w) < 2 or any(not 0 < v < 1e6 for v in w) or w != sorted(set(w)):
        raise UserError(f"--weights-g {text!r}: at least two different positive masses, rising")
    return w


def load_steps(masses_g: Sequence[float]) -> list[tuple[float, bool]]:
    """(mass [g], loading) in the order they are applied: up through every mass, then back down."""
    up = [(m, True) for m in masses_g]
    return up + [(m, False) for m in reversed(masses_g[:-1])] + [(0.0, False)]


def measure(hw: HardwareInterface, channel: int, masses_g: Sequence[float], place: Callable[[float, bool], Any],
            settle_s: float = 1.0, average_s: float = 0.5) -> tuple[float, list[CalibrationPoint]]:
    """Tare (no load), then each load step: ``place(mass_g, loading)`` asks for it (or applies it),
    the reading settles for ``settle_s`` and is averaged over ``average_s``. Returns (tare counts,
    points in order; the final unloaded reading is a point at 0 N)."""

    def reading() -> float:
        hw.discard_pending()
        collect(hw, settle_s)
        got = collect(hw, average_s)
        if not got:
            raise HardwareError("no samples while measuring")
        return statistics.fmean(s.adc0 if channel == 0 else s.adc1 for s in got)

    place(0.0, True)
    tare = reading()
    points = [CalibrationPoint(0.0, tare, True)]
    for mass, loading in load_steps(masses_g):
        place(mass, loading)
        points.append(CalibrationPoint(mass / 1000.0 * G0, reading(), loading))
    return tare, points


def report(cal: Calibration, rms: dict[str, float], points: list[CalibrationPoint]) -> Table:
    d = cal.data
    t = Table(title=f"calibration of {d.sensor_id}: {d.model}, fit RMS {d.fit_rms_n:.3f} N, "
                    f"hysteresis {d.hysteresis_pct_fs:.1f} % of {d.max_calibrated_force_n:.2f} N")
    for col in ("load [N]", "direction", "counts", "fit [N]", "residual [N]"):
        t.add_column(col)
    for p in points:
        f = float(cal.force_n(p.counts))
        t.add_row(f"{p.force_n:.3f}", "up" if p.loading else "down", f"{p.counts:.1f}", f"{f:.3f}",
                  f"{f - p.force_n:+.3f}")
    t.caption = "candidates (RMS residual): " + ", ".join(f"{k} {v:.3f} N" for k, v in rms.items())
    return t


def reference_line(calibration: Path, config: Path) -> str:
    """How the config names the calibration: ``force_calibration`` is read relative to the config's
    own folder, so the path printed is too (``../calibrations/s1.toml`` from configs/)."""
    rel = Path(os.path.relpath(Path(calibration).resolve(), Path(config).resolve().parent)).as_posix()
    return f"reference it in {config} with [rig] force_calibration = \"{rel}\" (a path from its folder)"


def add_parser(sub: argparse._SubParsersAction) -> argparse.ArgumentParser:
    p = sub.add_parser("calibrate", help="calibrate a sensor with known loads (force: the Flexiforce on A0)")
    p.add_argument("what", choices=("force",))
    p.add_argument("--config", type=config_file, help="plant config (configs/*.toml)")
    p.add_argument("--device", default=None, type=device_arg,
                   help="sim, avr, auto or a serial path (default: [rig].port)")
    p.add_argument("--sensor-id", help="the sensor's label (names calibrations/<id>.toml)")
    p.add_argument("--weights-g", type=weights_g, help="known masses in grams, rising: 50,100,200,500")
    p.add_argument("--circuit", choices=("opamp", "divider"), default="opamp", help="how the sensor reaches A0")
    p.add_argument("--channel", type=int, choices=(0, 1), default=0, help="ADC channel (the firmware limits A0)")
    p.add_argument("--settle", type=float, default=2.0, help="wait after placing a weight [s]")
    p.add_argument("--average", type=float, default=1.0, help="average the reading over [s]")
    p.add_argument("--out-dir", type=Path, default=Path("calibrations"))
    p.add_argument("--yes", action="store_true", help="do not wait for Enter (the loads are applied by a script)")
    p.add_argument("--points", type=Path, help="fit published points offline (CSV sensor,load_n,raw_counts), no device")
    return p


def run(args: argparse.Namespace) -> int:
    if args.points is not None:
        from rehab_hil.cli.calibrate_points import run_points

        return run_points(args.points)
    if args.config is None or args.sensor_id is None or args.weights_g is None:
        raise UserError("calibrate force needs --config, --sensor-id and --weights-g (or --points CSV)")
    from rehab_hil.cli.doctor import open_for_checks
    from rehab_hil.loading import load_config
    from rehab_hil.plants import get_plant

    cfg = load_config(args.config)
    binding = get_plant(cfg.plant).device(cfg)
    device = args.device or cfg.rig.port
    console = Console()
    if binding.adc and len(binding.adc) > args.channel and binding.adc[args.channel].kind != "force":
        console.print(f"note: ADC{args.channel} of {cfg.plant} is {binding.adc[args.channel].signal}, not a force")

    hand = None  # a simulated device's hand puts the weights on its sensor (doctor.SimulatedHand)

    def place(mass_g: float, loading: bool) -> None:
        what = "remove every load" if mass_g == 0 else f"{'place' if loading else 'leave'} {mass_g:g} g on the sensor"
        console.print(f"calibrate: {what}")
        if hand is not None and hand.load(args.channel, mass_g * G0 / 1000.0):
            return
        if not args.yes:
            input("press Enter when it rests ... ")

    try:
        with open_for_checks(device, args.config, cfg, binding, not args.yes, console.print) as (hw, hand):
            hw.configure(locked_configure(firmware_configure_fallback(cfg, binding)))
            tare, points = measure(hw, args.channel, args.weights_g, place, args.settle, args.average)
    except HardwareError as e:
        raise UserError(f"--device {device}: {e}") from None
    try:
        cal, rms = fit_calibration(points, tare, args.sensor_id, args.circuit)
    except ValueError as e:
        raise UserError(f"calibration: {e}") from None
    console.print(report(cal, rms, points))
    path = write_calibration(cal, args.out_dir)
    console.print(f"wrote {path}; {reference_line(path, args.config)}")
    return 0
