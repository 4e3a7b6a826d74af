"""The safety's temperature estimate against the simulated rig's truth, and every controller's temperature
budget, before and after issue 47 items 1 and 2 (docs/safety.md, "Which temperature the safety uses").

Two parts, each session through ``open_session`` on the in-process rig (lockstep, deterministic), its
recording's ``estimated_temperature_c`` (the supervisor's estimate, what trips ``temperature``) read beside
the device's ``sim_truth.csv`` (the actuator's true temperature on the simulated rig):

* ``rooms``: the SMA exoskeleton's shipped session (``model_based``, the twin beside it, 60 s) on rigs that
  differ from the config the way a lab's day does (``--sim-plant``: the shipped config with ONE value
  changed: the room 16, 23, 30, 40 C; the convection -30 / +30 %; the supply -10 / +10 %; and the nominal
  and the +7 C room with the controller's table kept as planned, no re-plan). Per rig: the supervisor's
  peak estimate and the true peak, over the session and after the twin's first window (12.5 s: before it
  nobody can know the room); the largest gap |estimate - truth| over both; the largest under-estimate
  (truth above the estimate: the side that matters for safety); the safety events; the twin's changes
  of the safety's values.
* ``budgets``: every controller with a ``[controllers.<name>]`` table in each plant's shipped config, with
  no simulated patient and with each shipped one (``profiles/sim/``), 180 s: the supervisor's peak
  estimate against the controller's temperature budget (its ``temperature_budget_c``, else the rig's
  ``max_temperature_c``), and the true peak.

"Before" runs the code and the configs of ``--base`` (default: the commit that added the truth file to
main's safety, so both sides have a truth to compare with), unpacked from git into a temporary folder;
"after" runs this tree. Each side's figures go to ``bench/results/thermal_truth_<side>.json``; the two
are printed beside each other (``--print`` prints the files that are there without running anything).

    .venv/bin/python bench/thermal_truth.py [--sides before,after] [--parts rooms,budgets] [--quick]
        [--base COMMIT] [--print]
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[1]
RESULTS = ROOT / "bench" / "results"
BASE = "66ac9a6"  # main's safety (3960d3d) with the truth file of every simulated rig: the 'before'
SMA = "configs/sma_exoskeleton.toml"
ROOMS = [  # (name, config key, value, re-plan): seed 000 Table 5's 23 C, 300 W/(m^2 C), 32 V moved as a lab's day does
    ("nominal", None, None, True), ("room 16 C", "sma.ambient_c", 16.0, True),
    ("room 30 C (+7)", "sma.ambient_c", 30.0, True), ("room 40 C", "sma.ambient_c", 40.0, True),
    ("convection -30 %", "sma.h1_w_per_m2_c", 210.0, True), ("convection +30 %", "sma.h1_w_per_m2_c", 390.0, True),
    ("supply -10 %", "drive.supply_voltage_v", 28.8, True), ("supply +10 %", "drive.supply_voltage_v", 35.2, True),
    # the controller's table kept as planned on the config (no re-plan on the twin's values): the wire runs as
    # much hotter as the room makes it, the case the target's "truth about +7 C" describes
    ("nominal, table kept", None, None, False), ("room 30 C (+7), table kept", "sma.ambient_c", 30.0, False)]
PLANTS = ("sma_exoskeleton", "tcp_finger", "finger_extensor")
PATIENTS = ("capable", "fatiguing", "passive", "slacking", "spastic", "weak")
FIRST_WINDOW_S = 12.5  # the twin's first thermal window on the SMA (one 12 s cycle), fitted and taken [s]


# -- one session, in a worker process running the side's code ------------------------------------
def worker(spec: dict[str, Any]) -> dict[str, Any]:
    """One session as ``spec`` says; its figures (run in the side's tree: only public API)."""
    import numpy as np

    from rehab_hil.controllers.build import settings_for
    from rehab_hil.loading import load_config
    from rehab_hil.patient.truth import read_truth
    from rehab_hil.service.session import SessionError, open_session

    cfg = load_config(spec["config"])
    name = spec.get("controller") or cfg.rig.session.controller
    own = getattr(settings_for(cfg, name), "temperature_budget_c", None)
    limit = cfg.rig.limits.max_temperature_c
    out: dict[str, Any] = {"controller": name, "budget_c": min(limit, own) if own is not None else limit}
    with tempfile.TemporaryDirectory() as tmp:
        os.environ["REHAB_HIL_LEARNING_DIR"] = str(Path(tmp) / "learning")
        os.environ["REHAB_HIL_ASSISTANCE_DIR"] = str(Path(tmp) / "assistance")
        try:
            with open_session(spec["config"], "inprocess", controller=name, sim_plant=spec.get("sim_plant"),
                              sim_patient=spec.get("patient"), twin=spec.get("twin", False), record=tmp,
                              thermal_replan=spec.get("replan", True)) as s:
                res = s.run(spec["duration_s"])
                run_dir = s.run_dir
        except SessionError as e:
            return {**out, "refused": str(e)}
        est = np.genfromtxt(run_dir / "run.csv", delimiter=",", names=True)
        truth = read_truth(run_dir / "sim_truth.csv")
        meta = json.loads((run_dir / "metadata.json").read_text())
    t, e = est["time_s"], est["estimated_temperature_c"]
    out.update(events=[f"{ev.reason} at {ev.t_s:.1f} s" for ev in res.events], peak_estimate_c=float(np.nanmax(e)),
               rmse_deg=res.session.get("rmse_deg", float("nan")))
    temp = next((k for k in truth if k.endswith("_temperature_c")), None)
    if temp is not None:
        true = np.interp(t, truth["t_s"], truth[temp])
        gap, late = e - true, t >= FIRST_WINDOW_S
        out.update(peak_truth_c=float(true.max()), max_gap_c=float(np.abs(gap).max()),
                   peak_estimate_late_c=float(e[late].max()) if late.any() else float("nan"),
                   peak_truth_late_c=float(true[late].max()) if late.any() else float("nan"),
                   max_gap_after_first_window_c=float(np.abs(gap[late]).max()) if late.any() else float("nan"),
                   max_under_c=float(max(-gap.min(), 0.0)),
                   max_under_after_first_window_c=float(max(-gap[late].min(), 0.0)) if late.any() else float("nan"))
    out["safety_thermal"] = meta.get("safety_thermal", {}).get("changes", [])
    return out


def run_worker(tree: Path, bench: Path, spec: dict[str, Any]) -> dict[str, Any]:
    """``worker(spec)`` in a process whose ``rehab_hil`` is the side's tree."""
    env = {**os.environ, "PYTHONPATH": f"{tree / 'src'}{os.pathsep}{tree}"}
    got = subprocess.run([sys.executable, str(bench), "--worker", json.dumps(spec)], env=env, cwd=tree,
                         capture_output=True, text=True)
    if got.returncode != 0:
        return {"error": (got.stderr.strip().splitlines() or ["?"])[-1]}
    return json.loads(got.stdout.strip().splitlines()[-1])


# -- the sides -----------------------------------------------------------------------------------
def side_tree(side: str, base: str, tmp: Path) -> Path:
    """This tree ("after"), or ``base``'s src, configs and profiles unpacked under ``tmp`` ("before")."""
    if side == "after":
        return ROOT
    dest = tmp / f"base-{base}"
    dest.mkdir()
    archive = subprocess.run(["git", "-C", str(ROOT), "archive", base, "src", "configs", "profiles"], check=True,
                             capture_output=True).stdout
    subprocess.run(["tar", "-x", "-C", str(dest)], input=archive, check=True)
    return dest


def room_rig(tree: Path, key: str | None, value: float | None, out: Path) -> Path | None:
    """The side's SMA config with ``key`` set to ``value`` (the simulated rig's plant), or None (nominal)."""
    if key is None:
        return None
    sys.path.insert(0, str(ROOT / "bench"))
    from robustness import set_key

    out.write_text(set_key((tree / SMA).read_text(), key, value))
    return out


def rooms(tree: Path, bench: Path, tmp: Path, quick: bool, only: list[str]) -> list[dict[str, Any]]:
    rows = []
    for i, (name, key, value, replan) in enumerate(ROOMS[:4] if quick else ROOMS):
        if only and name not in only:
            continue
        rig = room_rig(tree, key, value, tmp / f"rig{i}.toml")
        spec = {"config": str(tree / SMA), "sim_plant": str(rig) if rig else None, "twin": True,
                "duration_s": 36.0 if quick else 60.0, "replan": replan}
        t0 = time.monotonic()
        rows.append({"rig": name, **run_worker(tree, bench, spec), "wall_s": time.monotonic() - t0})
        print(f"  rooms  {name:18s} {_room_line(rows[-1])}", flush=True)
    return rows


def budgets(tree: Path, bench: Path, quick: bool) -> list[dict[str, Any]]:
    rows = []
    patients = (None, "weak", "fatiguing", "passive") if quick else (None, *PATIENTS)
    for plant in PLANTS:
        config = tree / "configs" / f"{plant}.toml"
        for name in _controllers(config):
            for patient in patients:
                spec = {"config": str(config), "controller": name, "duration_s": 90.0 if quick else 180.0,
                        "patient": str(tree / "profiles" / "sim" / f"{patient}.toml") if patient else None}
                row = {"plant": plant, "patient": patient or "none", **run_worker(tree, bench, spec)}
                rows.append(row)
                print(f"  budget {plant:16s} {name:17s} {row['patient']:10s} {_budget_line(row)}", flush=True)
    return rows


def _controllers(config: Path) -> list[str]:
    """The controllers a config has a table for, in its order."""
    import tomllib

    return list(tomllib.loads(config.read_text()).get("controllers", {}))


# -- printing ------------------------------------------------------------------------------------
def _f(v: Any, fmt: str = "6.1f") -> str:
    return format(v, fmt) if isinstance(v, int | float) else f"{'-':>6s}"


def _room_line(r: dict[str, Any]) -> str:
    if "error" in r or "refused" in r:
        return r.get("error") or r["refused"]
    return (f"peak est {_f(r['peak_estimate_c'])} truth {_f(r.get('peak_truth_c'))}  after 12.5 s est "
            f"{_f(r.get('peak_estimate_late_c'))} truth {_f(r.get('peak_truth_late_c'))}  "
            f"|gap| max {_f(r.get('max_gap_c'))}"
            f" after 12.5 s {_f(r.get('max_gap_after_first_window_c'))}  under max {_f(r.get('max_under_c'))} after"
            f" {_f(r.get('max_under_after_first_window_c'))}  events {len(r['events'])} changes "
            f"{len(r.get('safety_thermal', []))}")


def _budget_line(r: dict[str, Any]) -> str:
    if "error" in r or "refused" in r:
        return f"({r.get('error') or r['refused'][:90]})"
    over = r["peak_estimate_c"] - r["budget_c"]
    return (f"est {_f(r['peak_estimate_c'])} / budget {_f(r['budget_c'])} {'OVER' if over > 0 else 'ok  '} "
            f"truth {_f(r.get('peak_truth_c'))}  {', '.join(r['events']) or '-'}")


def print_sides(results: dict[str, dict[str, Any]]) -> None:
    """The two sides beside each other, row by row."""
    sides = [s for s in ("before", "after") if s in results]
    for part, key, line in (("rooms", ("rig",), _room_line),
                            ("budgets", ("plant", "controller", "patient"), _budget_line)):
        if not any(part in results[s] for s in sides):
            continue
        print(f"\n{part}:")
        index = {s: {tuple(r.get(k) for k in key): r for r in results[s].get(part, [])} for s in sides}
        order = list(dict.fromkeys(k for s in sides for k in index[s]))
        for k in order:
            print(" ".join(str(x) for x in k))
            for s in sides:
                if k in index[s]:
                    print(f"    {s:6s} {line(index[s][k])}")
        for s in sides:
            rows = [r for r in results[s].get(part, []) if "peak_estimate_c" in r]
            if part == "budgets":
                over = [r for r in rows if r["peak_estimate_c"] > r["budget_c"]]
                print(f"  {s}: {len(over)} of {len(rows)} sessions with the estimate above the budget")


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--worker", default=None, help=argparse.SUPPRESS)
    ap.add_argument("--sides", default="before,after")
    ap.add_argument("--parts", default="rooms,budgets")
    ap.add_argument("--base", default=BASE, help="the commit whose code and configs are 'before'")
    ap.add_argument("--quick", action="store_true", help="four rooms (36 s); three patients and none (90 s)")
    ap.add_argument("--print", action="store_true", help="print the results files there are, run nothing")
    ap.add_argument("--rooms", default="", help="only these rigs of the rooms part, ';'-separated names")
    args = ap.parse_args()
    if args.worker is not None:
        print(json.dumps(worker(json.loads(args.worker))))
        return 0
    RESULTS.mkdir(parents=True, exist_ok=True)
    if not args.print:
        with tempfile.TemporaryDirectory(prefix="thermal-truth-") as tmp_s:
            tmp = Path(tmp_s)
            bench = tmp / "thermal_truth.py"  # a copy: an edit of this file while it runs changes nothing
            shutil.copy(__file__, bench)
            for side in args.sides.split(","):
                tree = side_tree(side, args.base, tmp)
                print(f"{side}: {tree}", flush=True)
                got: dict[str, Any] = {"commit": args.base if side == "before" else _head(), "quick": args.quick}
                if "rooms" in args.parts:
                    got["rooms"] = rooms(tree, bench, tmp, args.quick, [r for r in args.rooms.split(";") if r])
                if "budgets" in args.parts:
                    got["budgets"] = budgets(tree, bench, args.quick)
                save(side, got)
    found = {s: json.loads((RESULTS / f"thermal_truth_{s}.json").read_text()) for s in ("before", "after")
             if (RESULTS / f"thermal_truth_{s}.json").exists()}
    print_sides(found)
    return 0


def save(side: str, got: dict[str, Any]) -> None:
    """Into ``thermal_truth_<side>.json``, over the rows of the same rig or session already there."""
    path = RESULTS / f"thermal_truth_{side}.json"
    old = json.loads(path.read_text()) if path.exists() else {}
    for part, key in (("rooms", ("rig",)), ("budgets", ("plant", "controller", "patient"))):
        if part in got:
            rows = {tuple(r.get(k) for k in key): r for r in old.get(part, [])}
            rows.update({tuple(r.get(k) for k in key): r for r in got[part]})
            got[part] = list(rows.values())
    path.write_text(json.dumps({**old, **got}, indent=1))


def _head() -> str:
    return subprocess.run(["git", "-C", str(ROOT), "rev-parse", "--short", "HEAD"], capture_output=True,
                          text=True).stdout.strip()


if __name__ == "__main__":
    sys.exit(main())
