"""Several records at once, effects chosen as a set (issue 38): a servo's records of both directions.

Four open-loop drive-step records of 20 s at 1 kHz (``discrepancy.synthetic.step_records``, two
turning each way, angle noise 0.01 deg) of the rotary axis of ``configs/servo_axis_nominal.toml``
with a Coulomb friction of 0.030 N m turning + and 0.012 N m turning -, and a viscous friction
1.7x the catalogue's. The workflow runs on all four from the CLI (``rehab-hil discrepancy --data
... x4``, a warm engine cache) from the nominal model (neither term) and from the reference model
(both terms in the config): wall time, what is named, and the friction levels beside an
independent least-squares fit of the same records (velocity and acceleration from a
Savitzky-Golay filter of the angle; g u = J a + b w + c+ [w > 0] - c- [w < 0] by linear least
squares on the moving samples: no simulation, no code of the workflow).
Writes bench/results/discrepancy_records.json. Usage: python bench/discrepancy_records.py [--duration 20]
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
from scipy.signal import savgol_filter

from rehab_hil.discrepancy.synthetic import step_records
from rehab_hil.interchange import write_csv
from rehab_hil.loading import load_config
from rehab_hil.plants import get_plant

ROOT = Path(__file__).resolve().parents[1]
HIDDEN = {"coulomb_friction_directional": {"level_pos_nm": 0.030, "level_neg_nm": 0.012}}
VISCOUS_FACTOR = 1.7
TARGET_WALL_S = 60.0
TARGET_LEVEL = 0.30  # levels within 30 % of the independent fit


def independent_fit(records: list, gain: float) -> dict[str, float]:
    """J, b, c+, c- by least squares on the moving samples of every record (module docstring)."""
    rows, rhs = [], []
    for r in records:
        q = np.radians(r.signals["angle_deg"])
        dt = float(np.median(np.diff(r.t)))
        w = savgol_filter(q, 41, 3, deriv=1, delta=dt)
        a = savgol_filter(q, 41, 3, deriv=2, delta=dt)
        moving = np.abs(w) > 5.0
        rows.append(np.column_stack([a, w, (w > 0).astype(float), -(w < 0).astype(float)])[moving])
        rhs.append(gain * r.signals["drive_input_v"][moving])
    coef, *_ = np.linalg.lstsq(np.vstack(rows), np.concatenate(rhs), rcond=None)
    return {"inertia_kg_m2": coef[0], "viscous_nm_s_per_rad": coef[1], "level_pos_nm": coef[2], "level_neg_nm": coef[3]}


def reference_config(nominal: Path, out: Path) -> Path:
    """The nominal config with the hidden terms in it: the reference model."""
    text = nominal.read_text()
    text = text.replace("viscous_nm_s_per_rad = 2.0e-4 ", f"viscous_nm_s_per_rad = {2.0e-4 * VISCOUS_FACTOR!r} ")
    p = HIDDEN["coulomb_friction_directional"]
    text += ("\n[[effects]]                         # the hidden friction (bench/discrepancy_records.py)\n"
             "name = \"coulomb_friction_directional\"\n"
             f"params = {{ level_pos_nm = {p['level_pos_nm']}, level_neg_nm = {p['level_neg_nm']} }}\n")
    out.write_text(text)
    return out


def run(cfg: Path, data: list[Path], out: Path) -> dict:
    args = [sys.executable, "-m", "rehab_hil.cli", "discrepancy", "--config", str(cfg), "--out", str(out),
            "--max-effects", "3"]
    for d in data:
        args += ["--data", str(d)]
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.perf_counter()
    p = subprocess.run(args, capture_output=True, text=True, cwd=ROOT)
    wall = time.perf_counter() - t0
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    cpu = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
    if p.returncode != 0:
        raise SystemExit(f"exit {p.returncode}\n{p.stdout}\n{p.stderr[-3000:]}")
    rep = json.loads((out / "report.json").read_text())
    chosen = {c["effect"]: c["params"] for c in rep["chosen"]}
    return {"wall_s": wall, "cpu_s": cpu, "load_1min": os.getloadavg()[0], "conclusion": rep["conclusion"],
            "chosen": chosen, "gaps": rep["gaps"], "stdout": p.stdout}


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--duration", type=float, default=20.0)
    a = ap.parse_args()
    nominal = ROOT / "configs" / "servo_axis_nominal.toml"
    cfg = load_config(nominal)
    spec = get_plant(cfg.plant)
    recs = step_records(spec, cfg, HIDDEN, duration_s=a.duration,
                        scale_params={"viscous.damping_nm_s_per_rad": VISCOUS_FACTOR}, seed=1)
    gain = cfg.drive.torque_constant_nm_per_v
    indep = independent_fit(recs, gain)
    out: dict = {"independent_fit": indep}
    with tempfile.TemporaryDirectory() as tmp:
        paths = [write_csv(Path(tmp) / f"servo_{i}.csv", r.t, r.signals) for i, r in enumerate(recs)]
        run(nominal, paths[:1], Path(tmp) / "warm")  # compile the engine once: the figures are warm runs
        out["nominal"] = run(nominal, paths, Path(tmp) / "nominal")
        out["reference"] = run(reference_config(nominal, Path(tmp) / "reference.toml"), paths, Path(tmp) / "ref")
    nom = out["nominal"]
    fitted = nom["chosen"].get("coulomb_friction_directional", {})
    print(f"{len(recs)} records of {a.duration:g} s at 1 kHz, from the nominal model (no Coulomb friction):")
    print(f"  wall {nom['wall_s']:.1f} s, CPU {nom['cpu_s']:.1f} s (target <= {TARGET_WALL_S:g} s wall on 2 cores; "
          f"load average {nom['load_1min']:.1f} from other work on the machine during the run)")
    print(f"  conclusion: {nom['conclusion']}")
    for k in ("level_pos_nm", "level_neg_nm"):
        f, i = fitted.get(k, float("nan")), indep[k]
        print(f"  {k}: workflow {f:.4g}, independent fit {i:.4g}, truth {HIDDEN['coulomb_friction_directional'][k]}"
              f" ({100 * (f / i - 1):+.1f} % vs the independent fit; target within {100 * TARGET_LEVEL:.0f} %)")
    print(f"  viscous: independent fit {indep['viscous_nm_s_per_rad']:.4g} N m s/rad "
          f"(truth {2e-4 * VISCOUS_FACTOR:.4g})")
    ref = out["reference"]
    print(f"from the reference model: wall {ref['wall_s']:.1f} s; conclusion: {ref['conclusion']}")
    res_dir = ROOT / "bench" / "results"
    res_dir.mkdir(exist_ok=True)
    (res_dir / "discrepancy_records.json").write_text(json.dumps(out, indent=2, default=float) + "\n")


if __name__ == "__main__":
    main()
