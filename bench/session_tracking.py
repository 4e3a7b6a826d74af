"""Session tracking through the real loop: the open-loop map, the PID and model-based control on each
plant's shipped session and one twice as fast, on the simulated rigs; and behind the Uno's USB
bridge. Prints one table per plant and writes bench/results/session_tracking.json.

Every session is ``rehab-hil run ... --record`` as a user runs it (host loop, estimator, supervisor,
the controller runtime, the firmware's logic and the plant model); the figures are the run's own
``metadata.json``: per-cycle means (all complete cycles, the first from rest included), the worst
cycle's max error, the supervisor's peak temperature estimate, the electrical energy per cycle.
``inprocess`` is lockstep (deterministic, faster than real time); ``bridge`` is the Python device
on a pty in real time behind the 16U2 bridge model (samples arrive 2-4 at a time).

Also: the seed 002 step (59.58 deg) on the Finger Extensor direct and behind the bridge; a 10 min
SMA session; the model loop on a rig with a hidden effect (session -> ``rehab-hil discrepancy`` ->
``augmented.toml`` -> session); and the controller's step time on the loop.

Targets (issue 22): SMA RMSE <= 2 deg, max error <= 8 deg, peak estimated wire temperature <= A_f +
25 C = 103 C, energy per cycle >= 40 % below the open-loop map, no safety event in 10 min; TCP RMSE
<= 10 % of its range within its heating limits; FE RMSE <= 1 deg, step overshoot <= 2.86 deg and
rise <= 0.3 s, the same behind the bridge; an augmented model's controller halves the nominal
one's RMSE on a rig with the effect; the controller step <= 50 us p99.
Usage: python bench/session_tracking.py [--quick] [--skip-bridge] [--skip-loop] [--skip-long]
"""

from __future__ import annotations

import argparse
import contextlib
import io
import json
import math
import platform
import re
import tempfile
import time
from pathlib import Path

import numpy as np

from rehab_hil.cli import main
from rehab_hil.loading import load_config
from rehab_hil.loop.estimation import State
from rehab_hil.service import assembly

ROOT = Path(__file__).resolve().parents[1]
CONFIGS = ROOT / "configs"
PLANTS = ("sma_exoskeleton", "tcp_finger", "finger_extensor")
CONTROLLERS = ("open_loop_map", "pulsed", "pid", "model_based")
HIDDEN = (("sma_exoskeleton", "actuator_dead_zone", "width_duty = 0.08"),
          ("sma_exoskeleton", "sma_hysteresis", "width_c = 10.0"),
          ("finger_extensor", "coulomb_friction", "level_nm = 0.1"))


def variant(plant: str, dest: Path, *, faster: bool = False, bridge: bool = False,
            effect: tuple[str, str] | None = None, text: str | None = None) -> Path:
    """A copy of the plant's config: twice the cycles per minute, the USB bridge on, an effect added."""
    src = text if text is not None else (CONFIGS / f"{plant}.toml").read_text()
    if faster:
        m = re.search(r"(\[rig\.session\][^\[]*?cycles_per_minute = )([0-9.]+)", src, re.S)
        assert m, "no [rig.session] cycles_per_minute"
        src = src[:m.start(2)] + repr(2 * float(m.group(2))) + src[m.end(2):]
    if bridge:
        src = src.replace("usb_bridge = false", "usb_bridge = true")
    if effect is not None:
        src += f'\n[[effects]]\nname = "{effect[0]}"\nparams = {{ {effect[1]} }}\n'
    dest.write_text(src)
    return dest


def session(config: Path, out: Path, *, controller: str | None = None, device: str = "inprocess",
            duration: float | None = None, sim_plant: Path | None = None, reference: str = "session") -> dict:
    """One recorded ``rehab-hil run``; its metadata.json (or the refusal it printed)."""
    cfg = load_config(config)
    ses = cfg.rig.session
    period = 60.0 / ses.cycles_per_minute
    hold = 0.5 * (period - 2 * ses.move_fraction * period)
    dur = duration if duration is not None else hold + 3 * period + 0.2
    args = ["run", "--config", str(config), "--device", device, "--duration", f"{dur:g}", "--record", str(out),
            "--no-display", "--home", "none", "--reference", reference]
    if controller:
        args += ["--controller", controller]
    if sim_plant is not None:
        args += ["--sim-plant", str(sim_plant)]
    buf_out, buf_err = io.StringIO(), io.StringIO()
    t0 = time.perf_counter()
    with contextlib.redirect_stdout(buf_out), contextlib.redirect_stderr(buf_err):
        code = main(args)
    wall = time.perf_counter() - t0
    if code == 2:  # refused: one line says why
        return {"refused": buf_err.getvalue().strip().splitlines()[-1]}
    run = sorted(out.iterdir())[-1]
    meta = json.loads((run / "metadata.json").read_text())
    meta["wall_s"], meta["run_dir"] = wall, str(run)
    return meta


def figures(meta: dict) -> dict:
    if "refused" in meta:
        return {"refused": meta["refused"]}
    s = meta.get("session", {})
    return {"rmse_deg": s.get("rmse_deg", math.nan), "max_error_deg": s.get("max_error_deg", math.nan),
            "session_rmse_deg": meta["tracking"].get("rmse", math.nan), "cycles": s.get("cycles", 0.0),
            "rom_deg": s.get("rom_deg", math.nan), "time_to_open_s": s.get("time_to_open_s", math.nan),
            "time_to_closed_s": s.get("time_to_closed_s", math.nan),
            "peak_temperature_c": s.get("peak_temperature_c", math.nan),
            "energy_per_cycle_j": s.get("energy_per_cycle_j", math.nan),
            "safety": [e["reason"] for e in meta["safety_events"]], "reaction_p99_us": meta["timing"].get(
                "lateness_p99_us", math.nan), "wall_s": meta["wall_s"]}


def table(title: str, rows: dict[str, dict]) -> None:
    print(f"\n{title}")
    head = (f"{'controller':28s} {'RMSE':>6s} {'max':>6s} {'ROM':>6s} {'t_open':>6s} {'t_close':>7s} {'T_peak':>7s} "
            f"{'E/cycle':>8s} {'cycles':>6s}  safety")
    print(head + "\n" + "-" * len(head))
    for name, f in rows.items():
        if "refused" in f:
            print(f"{name:28s} refused: {f['refused'][:110]}")
            continue
        print(f"{name:28s} {f['rmse_deg']:6.2f} {f['max_error_deg']:6.2f} {f['rom_deg']:6.1f} "
              f"{f['time_to_open_s']:6.2f} {f['time_to_closed_s']:7.2f} {f['peak_temperature_c']:7.1f} "
              f"{f['energy_per_cycle_j']:8.1f} {f['cycles']:6.0f}  {','.join(f['safety']) or 'none'}")


def step_figures(meta: dict, target: float) -> dict:
    """The step's figures from the run's files (rehab_hil.run_figures: the function the run's own
    summary and metadata.json use, so the two agree)."""
    from rehab_hil.run_figures import run_figures

    if "refused" in meta:
        return {"refused": meta["refused"]}
    m = run_figures(Path(meta["run_dir"]))["step_response"] or {}
    return {"overshoot_deg": m.get("overshoot", math.nan), "rise_time_s": m.get("rise_time_s", math.nan),
            "settling_time_s": m.get("settling_time_s", math.nan), "target_deg": m.get("target", target),
            "safety": [e["reason"] for e in meta["safety_events"]]}


def step_time(plant: str, controller: str, n: int = 20_000) -> dict:
    """The controller's step on the loop (ControllerRuntime.__call__), timed one call at a time."""
    cfg = load_config(CONFIGS / f"{plant}.toml")
    rt = assembly.build_controller(cfg, controller)
    period = assembly.period_s(cfg)
    ts = np.empty(n)
    for k in range(n):
        analog = {ch.signal: 0.0 for ch in rt.controller.ctx.binding.adc}
        st = State(k * period, 0.3 + 0.1 * math.sin(k * 1e-3), 0.1, analog)
        t0 = time.perf_counter_ns()
        rt(k * period, st)
        ts[k] = time.perf_counter_ns() - t0
    ts = ts[1000:] / 1000.0
    return {"p50_us": float(np.percentile(ts, 50)), "p99_us": float(np.percentile(ts, 99)),
            "p99_9_us": float(np.percentile(ts, 99.9)), "max_us": float(ts.max())}


def main_bench() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="shipped speed only, no TCP behind the bridge")
    ap.add_argument("--skip-bridge", action="store_true", help="no real-time sessions behind the USB bridge")
    ap.add_argument("--skip-loop", action="store_true", help="no model loop (discrepancy) cases")
    ap.add_argument("--skip-long", action="store_true", help="no 10 min SMA session")
    ap.add_argument("--out", type=Path, default=ROOT / "bench" / "results" / "session_tracking.json")
    args = ap.parse_args()
    results: dict = {"host": platform.node(), "python": platform.python_version(), "plants": {}}
    tmp = Path(tempfile.mkdtemp(prefix="session-tracking-"))
    for plant in PLANTS:
        rows: dict[str, dict] = {}
        for speed in ("shipped",) if args.quick else ("shipped", "2x faster"):
            cfg_path = variant(plant, tmp / f"{plant}-{speed[:2]}.toml", faster=speed != "shipped")
            for ctl in CONTROLLERS:
                meta = session(cfg_path, tmp / f"runs-{plant}-{speed[:2]}-{ctl}", controller=ctl)
                if "refused" in meta and "missing table" in meta["refused"]:
                    continue  # the plant has no settings for it: not one of its controllers
                rows[f"{ctl} ({speed})"] = figures(meta)
        if not args.skip_bridge and not (args.quick and plant == "tcp_finger"):
            bridged = variant(plant, tmp / f"{plant}-bridge.toml", bridge=True)
            cfg = load_config(bridged)
            period = 60.0 / cfg.rig.session.cycles_per_minute
            hold = 0.5 * (period - 2 * cfg.rig.session.move_fraction * period)
            cycles = 1 if plant == "tcp_finger" else 2
            for ctl in ("pid", "model_based"):
                meta = session(bridged, tmp / f"runs-{plant}-bridge-{ctl}", controller=ctl, device="sim",
                               duration=hold + cycles * period + 0.2)
                rows[f"{ctl} (shipped, USB bridge)"] = figures(meta)
        table(f"{plant}: per-cycle means (RMSE, max [deg], ROM [deg], times [s], peak est. T [C], E [J])", rows)
        results["plants"][plant] = rows

    fe = load_config(CONFIGS / "finger_extensor.toml")
    target = fe.rig.session.step_deg
    steps = {}
    for link in ("direct", "USB bridge") if not args.skip_bridge else ("direct",):
        path = variant("finger_extensor", tmp / f"fe-step-{link[:3]}.toml", bridge=link != "direct")
        for ctl in ("pid", "model_based"):
            meta = session(path, tmp / f"runs-step-{link[:3]}-{ctl}", controller=ctl, device="sim", duration=3.0,
                           reference="step")
            steps[f"{ctl} ({link})"] = step_figures(meta, target)
    print(f"\nFinger Extensor step to {target} deg (seed 002: overshoot 2.86 deg, ~0.3 s); sim device, real time")
    for name, f in steps.items():
        print(f"  {name:26s} overshoot {f.get('overshoot_deg', math.nan):5.2f} deg  rise "
              f"{f.get('rise_time_s', math.nan):.3f} s  settling {f.get('settling_time_s', math.nan):.3f} s  "
              f"safety {','.join(f.get('safety', [])) or 'none'}")
    results["fe_step"] = steps

    if not args.skip_long:
        meta = session(CONFIGS / "sma_exoskeleton.toml", tmp / "runs-sma-10min", duration=600.0)
        results["sma_10_min"] = figures(meta)
        f = results["sma_10_min"]
        print(f"\nSMA, 10 min model-based session (in-process): {f['cycles']:.0f} cycles, RMSE "
              f"{f['rmse_deg']:.2f} deg, worst max error {f['max_error_deg']:.2f} deg, peak est. T "
              f"{f['peak_temperature_c']:.1f} C, safety {','.join(f['safety']) or 'none'} ({f['wall_s']:.0f} s wall)")

    if not args.skip_loop:
        print("\nModel loop on a rig with a hidden effect: session with the nominal model's controller -> discrepancy "
              "-> augmented.toml -> session with the augmented model's controller (in-process, 3 cycles)")
        loops = {}
        for plant, name, params in HIDDEN:
            rig = variant(plant, tmp / f"rig-{name}.toml", effect=(name, params))
            before = session(CONFIGS / f"{plant}.toml", tmp / f"loop-{name}-before", sim_plant=rig)
            report = tmp / f"report-{name}"
            buf = io.StringIO()
            with contextlib.redirect_stdout(buf), contextlib.redirect_stderr(io.StringIO()):
                main(["discrepancy", "--config", str(CONFIGS / f"{plant}.toml"), "--data", before["run_dir"],
                      "--out", str(report)])
            rep = json.loads((report / "report.json").read_text())
            named = [f"{c['effect']}({', '.join(f'{k}={v:.3g}' for k, v in c['params'].items())})"
                     for c in rep.get("chosen", [])]
            after = session(report / "augmented.toml", tmp / f"loop-{name}-after", sim_plant=rig)
            b, a = figures(before), figures(after)
            loops[f"{plant} + {name} {params}"] = {"named": named, "before": b, "after": a}
            print(f"  {plant} + {name} ({params}): named {', '.join(named) or 'nothing'}; per-cycle RMSE "
                  f"{b['rmse_deg']:.2f} -> {a['rmse_deg']:.2f} deg ({b['rmse_deg'] / a['rmse_deg']:.1f}x), max "
                  f"{b['max_error_deg']:.2f} -> {a['max_error_deg']:.2f} deg, safety "
                  f"{','.join(b['safety']) or 'none'} -> {','.join(a['safety']) or 'none'}")
        results["model_loop"] = loops

    print("\nController step on the loop (ControllerRuntime, 20 000 calls, one core):")
    timing = {}
    for plant in PLANTS:
        for ctl in ("pid", "model_based"):
            timing[f"{plant}/{ctl}"] = t = step_time(plant, ctl)
            print(f"  {plant:16s} {ctl:12s} p50 {t['p50_us']:5.1f} us  p99 {t['p99_us']:5.1f} us  "
                  f"p99.9 {t['p99_9_us']:6.1f} us  max {t['max_us']:7.1f} us")
    results["controller_step"] = timing
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(results, indent=1, default=str))
    print(f"\nwrote {args.out}")


if __name__ == "__main__":
    main_bench()
