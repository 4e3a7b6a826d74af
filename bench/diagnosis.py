"""The twin's quick diagnosis on mid-session changes (issue 23, item 4): is the likeliest cause
named correctly, and what does a call cost on one core?

Each case is a window of ``WINDOW_S`` from the moment the plant changes
(``twin.diagnosis.changed_window``: the plant's own excitation, sensor noise, 800 Hz logger, the
rig's columns only), diagnosed with
the twin's state at the window's start (what the twin hands over) and without it (the workflow's
start estimate). A case counts as correct when the likeliest cause is of the changed quantity's
family ("passive stiffness" for a stiffness doubling, whichever of the effect or the parameter is
named). A change the window does not show (``_visible``: the same window without the change differs
by less than the noise gate on every channel) is counted apart: no diagnosis can name it. CPU time
is the calling thread's (``time.thread_time``), the numba kernels already loaded (as in the twin's
process).

    .venv/bin/python bench/diagnosis.py [--seeds 5] [--window 4]

Prints one line per case and the totals; writes bench/results/diagnosis.json.
"""

from __future__ import annotations

import argparse
import json
import statistics
import time
from pathlib import Path

import numpy as np

from rehab_hil.discrepancy.verdict import unexplained_channels
from rehab_hil.loading import load_config
from rehab_hil.plants import get_plant
from rehab_hil.plants.sections import EffectSpec
from rehab_hil.twin.diagnosis import changed_window, diagnose

ROOT = Path(__file__).resolve().parents[1]
WINDOW_S = 4.0


def _cases():
    """(plant, case, family expected, config the model runs, changed_window keywords)."""
    out = []
    fe = load_config(ROOT / "configs" / "finger_extensor.toml")
    tcp = load_config(ROOT / "configs" / "tcp_finger.toml")
    sma = load_config(ROOT / "configs" / "sma_exoskeleton.toml")
    contact_fe = {"stiffness_nm_per_rad": 0.3, "damping_nm_s_per_rad": 0.0, "contact_angle_rad": 0.4}
    # the TCP finger's MCP moves 0-12 deg under its excitation: the patient's contact from 3 deg on
    contact_tcp = {"stiffness_nm_per_rad": 0.01, "damping_nm_s_per_rad": 0.0, "contact_angle_rad": 0.05}
    muscle_tcp = {"scale_nm": 0.002, "shape_per_rad": 2.0, "damping_nm_s_per_rad": 0.0}
    muscle_sma = {"scale_nm": 0.02, "shape_per_rad": 2.0, "damping_nm_s_per_rad": 0.0}

    def patient(cfg, name, params):
        return cfg.model_copy(update={"effects": [EffectSpec(name=name, params=params)]})

    out += [
        ("finger_extensor", "coulomb friction 0.03 N m appears", "friction", fe,
         {"effects": {"coulomb_friction": {"level_nm": 0.03}}}),
        ("finger_extensor", "contact stiffness doubles", "passive stiffness",
         patient(fe, "contact_spring_damper", contact_fe), {"effects": {"contact_spring_damper": contact_fe}}),
        ("finger_extensor", "clean", None, fe, {}),
        ("tcp_finger", "coulomb friction 0.01 N m appears", "friction", tcp,
         {"effects": {"coulomb_friction": {"level_nm": 0.01}}}),
        ("tcp_finger", "contact stiffness doubles", "passive stiffness",
         patient(tcp, "contact_spring_damper", contact_tcp), {"effects": {"contact_spring_damper": contact_tcp}}),
        ("tcp_finger", "passive muscle doubles", "passive stiffness",
         patient(tcp, "passive_muscle", muscle_tcp), {"effects": {"passive_muscle": muscle_tcp}}),
        ("tcp_finger", "clean", None, tcp, {}),
        ("sma_exoskeleton", "supply sags 8 %", "supply voltage", sma, {"input_scale": {"supply_voltage_v": 0.92}}),
        ("sma_exoskeleton", "wire loses 15 % of its prestrain", "SMA wire prestrain", sma,
         {"config": sma.model_copy(update={"sma": sma.sma.model_copy(
             update={"prestrain": 0.85 * sma.sma.prestrain})})}),
        ("sma_exoskeleton", "passive muscle doubles", "passive stiffness",
         patient(sma, "passive_muscle", muscle_sma), {"effects": {"passive_muscle": muscle_sma}}),
        ("sma_exoskeleton", "contact pad stiffness doubles", "passive stiffness", sma,
         {"config": sma.model_copy(update={"contact": sma.contact.model_copy(
             update={"stiffness_n_per_m": 2.0 * sma.contact.stiffness_n_per_m})})}),
        ("sma_exoskeleton", "coulomb friction 0.01 N m appears", "friction", sma,
         {"effects": {"coulomb_friction": {"level_nm": 0.01}}}),
        ("sma_exoskeleton", "clean", None, sma, {}),
    ]
    return out


def _visible(changed, unchanged) -> bool:
    """Does the change show in the window at all? The same window without it (same drive, same
    noise draw) differs on some channel by more than the diagnosis's noise gate
    (``verdict.unexplained_channels``: 4 noise floors and 2 % of the spread): a change that moves
    nothing by that much gives the monitor nothing to fire on and no diagnosis anything to name."""
    chans = [c for c in changed.signals if c in unchanged.signals and not np.array_equal(changed[c], unchanged[c])]
    rms = {c: float(np.sqrt(np.mean((changed[c] - unchanged[c]) ** 2))) for c in chans}
    return bool(unexplained_channels(chans, {c: changed[c] for c in chans}, rms))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--seeds", type=int, default=5)
    ap.add_argument("--window", type=float, default=WINDOW_S)
    args = ap.parse_args()
    rows = []
    warm: set[str] = set()
    for plant, case, family, cfg, kw in _cases():
        spec = get_plant(plant)
        if plant not in warm:  # the twin's process has the kernels loaded already
            w = changed_window(spec, cfg, seed=0, window_s=args.window)
            t = time.thread_time()
            diagnose(spec, cfg, w.recording, w.x0, w.xd0)
            print(f"{plant}: first call (kernels loaded from the disk cache) {time.thread_time() - t:.2f} s CPU")
            warm.add(plant)
        for seed in range(1, args.seeds + 1):
            w = changed_window(spec, cfg, seed=seed, window_s=args.window, **kw)
            visible = _visible(w.recording, changed_window(spec, cfg, seed=seed, window_s=args.window).recording)
            for state in (True, False):
                d = diagnose(spec, cfg, w.recording, *((w.x0, w.xd0) if state else ()))
                named = d.likeliest.family if d.likeliest else None
                ok = named == family
                rank = next((i + 1 for i, c in enumerate(d.causes) if c.family == family), None) if family else None
                rows.append({"plant": plant, "case": case, "seed": seed, "twin_state": state, "expected": family,
                             "named": named, "correct": ok, "visible": visible, "rank_of_truth": rank,
                             "text": d.text, "cpu_s": d.cpu_s, "simulations": d.n_simulations})
                print(f"{plant:16s} {case:36s} seed {seed} {'state' if state else 'estim'} "
                      f"{'OK ' if ok else ('-- ' if not visible and family else 'XX ')}{d.cpu_s:5.2f} s  {d.text}")
    print()
    summary = {}
    for state in (True, False):
        sel = [r for r in rows if r["twin_state"] == state]
        changed = [r for r in sel if r["expected"]]
        shown = [r for r in changed if r["visible"]]
        clean = [r for r in sel if not r["expected"]]
        key = "twin_state" if state else "estimated_start"
        summary[key] = {
            "changes_correct": f"{sum(r['correct'] for r in changed)}/{len(changed)}",
            "visible_changes_correct": f"{sum(r['correct'] for r in shown)}/{len(shown)}",
            "clean_without_cause": f"{sum(r['correct'] for r in clean)}/{len(clean)}",
        }
        print(f"{key}: changes named correctly {summary[key]['changes_correct']}, of those the window shows "
              f"{summary[key]['visible_changes_correct']}; clean windows naming nothing "
              f"{summary[key]['clean_without_cause']}")
    for plant in dict.fromkeys(r["plant"] for r in rows):
        cpu = [r["cpu_s"] for r in rows if r["plant"] == plant]
        summary[f"cpu_s_{plant}"] = {"median": statistics.median(cpu), "max": max(cpu)}
        print(f"{plant}: CPU per call median {statistics.median(cpu):.2f} s, max {max(cpu):.2f} s "
              f"({args.window:g} s window)")
    out = ROOT / "bench" / "results" / "diagnosis.json"
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps({"window_s": args.window, "seeds": args.seeds, "summary": summary, "rows": rows},
                              indent=1))
    print(f"wrote {out}")


if __name__ == "__main__":
    main()
