"""Discrepancy workflow benchmark on the Finger Extensor (issue 8).

1. Wall time of the full workflow (every applicable effect, up to two rounds) on 60 s of 1 kHz
   data with a hidden Coulomb friction (target <= 30 s on the 2-core machine).
2. Detection over generated cases: >= 40 with a random hidden effect, magnitude, noise level and
   seed, and 10 clean ones (no effect). Reports the share named correctly (first named effect),
   false alarms (any effect named on clean data, or a wrong one), and the parameter error.

Every case has the realism of the tests: iris inertia +5 %, current noise, encoder quantisation,
logging at 800 Hz against the 1 kHz model. Prints a table; writes bench/results/discrepancy.json.
Usage: python bench/discrepancy.py [--hidden 40] [--clean 10] [--duration 12]
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import statistics
import time
from pathlib import Path

import numpy as np
from rich.console import Console
from rich.table import Table

from rehab_hil.discrepancy.replay import Replay
from rehab_hil.discrepancy.synthetic import hidden_effect_recording
from rehab_hil.discrepancy.workflow import Options, find_missing_effects
from rehab_hil.plants import get_plant, load_config

ROOT = Path(__file__).resolve().parents[1]
CONFIG = ROOT / "configs" / "finger_extensor.toml"

# magnitude ranges drawn from, per effect (uniform)
RANGES = {
    "coulomb_friction": {"level_nm": (0.01, 0.06)},
    "viscous_friction": {"damping_nm_s_per_rad": (0.01, 0.05)},
    "backlash": {"width_rad": (0.015, 0.06)},
    "time_delay": {"delay_s": (0.004, 0.03)},
    "contact_spring_damper": {"stiffness_nm_per_rad": (0.3, 1.5), "damping_nm_s_per_rad": (0.01, 0.06),
                              "contact_angle_rad": (0.2, 0.5)},
}


def timing(spec, cfg, replay) -> dict:
    rec = hidden_effect_recording(spec, cfg, {"coulomb_friction": {"level_nm": 0.03}}, duration_s=60.0,
                                  rate_hz=1000.0, seed=1, replay=replay)
    t0, c0 = time.perf_counter(), time.process_time()
    res = find_missing_effects(cfg, rec, "bench-60s.csv", options=Options(max_effects=2))
    wall, cpu = time.perf_counter() - t0, time.process_time() - c0
    sims = sum(c.fit.n_simulations for rd in res.rounds for c in rd.candidates)
    return {"data_s": 60.0, "rate_hz": 1000.0, "wall_s": wall, "cpu_s": cpu, "target_s": 30.0, "named": res.named,
            "rounds": len(res.rounds), "simulations": sims,
            "params": [f.params for f in res.chosen]}


def cases(n_hidden: int, n_clean: int, seed: int) -> list[dict]:
    rng = np.random.default_rng(seed)
    names = sorted(RANGES)
    out = []
    for i in range(n_hidden):
        eff = names[i % len(names)]  # balanced over the library, random within
        params = {k: float(rng.uniform(*r)) for k, r in RANGES[eff].items()}
        out.append({"effect": eff, "params": params, "noise_scale": float(rng.uniform(0.5, 2.0)),
                    "seed": int(rng.integers(1 << 30))})
    for _ in range(n_clean):
        out.append({"effect": None, "params": {}, "noise_scale": float(rng.uniform(0.5, 2.0)),
                    "seed": int(rng.integers(1 << 30))})
    return out


def run_case(spec, cfg, replay, case: dict, duration_s: float) -> dict:
    effects = {case["effect"]: case["params"]} if case["effect"] else {}
    rec = hidden_effect_recording(spec, cfg, effects, duration_s=duration_s, seed=case["seed"],
                                  noise_scale=case["noise_scale"], replay=replay)
    t0 = time.perf_counter()
    res = find_missing_effects(cfg, rec, "case.csv", options=Options(max_effects=1))
    row = {**case, "named": res.named, "wall_s": time.perf_counter() - t0}
    row["correct"] = (res.named[:1] == [case["effect"]]) if case["effect"] else (res.named == [])
    row["false_alarm"] = bool(res.named) and (case["effect"] is None or res.named[0] != case["effect"])
    if case["effect"] and row["correct"]:
        fitted = res.chosen[0].params
        row["fitted"] = fitted
        row["rel_error"] = {k: abs(fitted[k] - v) / abs(v) for k, v in case["params"].items()}
    return row


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--hidden", type=int, default=40)
    ap.add_argument("--clean", type=int, default=10)
    ap.add_argument("--duration", type=float, default=12.0, help="seconds of data per detection case")
    ap.add_argument("--seed", type=int, default=2026)
    ap.add_argument("--timing-only", action="store_true", help="only the 60 s timing (discrepancy_timing.json)")
    args = ap.parse_args()
    console = Console()
    spec, cfg = get_plant("finger_extensor"), load_config(CONFIG)
    replay = Replay.build(spec, cfg, hidden_effect_recording(spec, cfg, {}, duration_s=3.0))
    replay.simulate(replay.nominal_params())  # compile / load from cache outside the timings

    t = timing(spec, cfg, replay)
    console.print(f"60 s of 1 kHz data, full library: {t['wall_s']:.1f} s wall, {t['cpu_s']:.1f} s CPU "
                  f"(target <= 30 s), {t['simulations']} simulations, named {t['named']}")
    if args.timing_only:
        out = ROOT / "bench" / "results" / "discrepancy_timing.json"
        out.write_text(json.dumps({"timing_60s": t, "cpus": os.cpu_count(), "load_avg": os.getloadavg()},
                                  indent=2, default=float) + "\n")
        return
    rows = []
    all_cases = cases(args.hidden, args.clean, args.seed)
    for i, case in enumerate(all_cases, 1):
        row = run_case(spec, cfg, replay, case, args.duration)
        rows.append(row)
        console.print(f"[{i}/{len(all_cases)}] hidden {case['effect']} -> named {row['named']} "
                      f"({'ok' if row['correct'] else 'WRONG'}, {row['wall_s']:.1f} s)")

    table = Table(title=f"discrepancy detection ({args.duration:.0f} s per case, 800 Hz, noise x0.5-2)")
    for col in ("hidden effect", "cases", "named correctly", "false alarms", "median param error", "worst"):
        table.add_column(col)
    summary = {}
    for eff in [*sorted(RANGES), None]:
        sel = [r for r in rows if r["effect"] == eff]
        if not sel:
            continue
        errs = [max(r["rel_error"].values()) for r in sel if "rel_error" in r]
        s = {"cases": len(sel), "correct": sum(r["correct"] for r in sel),
             "false_alarms": sum(r["false_alarm"] for r in sel),
             "median_param_rel_error": statistics.median(errs) if errs else None,
             "max_param_rel_error": max(errs) if errs else None}
        summary[eff or "clean"] = s
        table.add_row(eff or "(clean)", str(s["cases"]), f"{s['correct']}/{s['cases']}", str(s["false_alarms"]),
                      "-" if not errs else f"{100 * s['median_param_rel_error']:.1f} %",
                      "-" if not errs else f"{100 * s['max_param_rel_error']:.1f} %")
    hidden = [r for r in rows if r["effect"]]
    clean = [r for r in rows if not r["effect"]]
    errs = [max(r["rel_error"].values()) for r in hidden if "rel_error" in r]
    totals = {
        "hidden_cases": len(hidden), "clean_cases": len(clean),
        "share_named_correctly": sum(r["correct"] for r in hidden) / max(len(hidden), 1),
        "false_alarms_on_clean": sum(r["false_alarm"] for r in clean),
        "wrong_effect_named": sum(r["false_alarm"] for r in hidden),
        "median_param_rel_error": statistics.median(errs) if errs else None,
        "median_case_wall_s": statistics.median(r["wall_s"] for r in rows) if rows else None,
    }
    console.print(table)
    console.print(totals)
    out = ROOT / "bench" / "results" / "discrepancy.json"
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps({
        "machine": {"cpus": os.cpu_count(), "python": platform.python_version(), "platform": platform.platform()},
        "timing_60s": t, "totals": totals, "per_effect": summary, "cases": rows,
        "settings": {"duration_s": args.duration, "rate_hz": 800.0, "seed": args.seed, "max_effects": 1},
    }, indent=2, default=float) + "\n")
    console.print(f"wrote {out.relative_to(ROOT)}")


if __name__ == "__main__":
    main()
