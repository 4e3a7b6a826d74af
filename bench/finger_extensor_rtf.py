"""Real-time factor of the Finger Extensor simulation at a 1 kHz step (target >= 500x on one core).

Prints the figures and writes bench/results/finger_extensor_rtf.json. Compilation is excluded
(it is a one-off per diagram structure, cached on disk) and reported separately.
"""

from __future__ import annotations

import json
import os
import platform
import statistics
import time
from pathlib import Path

from rehab_hil.loading import load_config
from rehab_hil.models.system import Diagram
from rehab_hil.plants import get_plant

ROOT = Path(__file__).resolve().parents[1]
SIM_SECONDS = 60.0
REPEATS = 5


def measure(system, n_steps: int, inputs: dict) -> list[float]:
    walls = []
    for _ in range(REPEATS):
        t0 = time.perf_counter()
        system.simulate(n_steps, inputs)
        walls.append(time.perf_counter() - t0)
    return walls


def main() -> dict:
    os.sched_setaffinity(0, {min(os.sched_getaffinity(0))})  # one core
    cfg = load_config(ROOT / "configs" / "finger_extensor.toml")
    spec = get_plant("finger_extensor")
    step_s, substeps = spec.step(cfg)
    n = int(SIM_SECONDS / step_s)
    results = {}
    cycle = spec.scenarios["cycle"](cfg)  # the rig's pid controller on open-close cycles
    cases = {
        "plant_open_loop": (spec.build(cfg), {"motor_voltage_v": 6.0}, ()),
        "closed_loop_pid_cycle": ([*spec.build(cfg), *cycle.parts], dict(cycle.inputs), cycle.sums),
    }
    for name, (parts, inputs, sums) in cases.items():
        t0 = time.perf_counter()
        # in the closed loop the PID produces motor_voltage_v; patient_torque_nm and the controller's
        # dt_s are external
        system = Diagram(parts, inputs=tuple(dict.fromkeys(("motor_voltage_v", "patient_torque_nm", *inputs))),
                         sums=(*spec.ports(cfg).sums, *sums)).compile(step_s, substeps)
        system.simulate(10, inputs)
        load_s = time.perf_counter() - t0
        walls = measure(system, n, inputs)
        best, med = min(walls), statistics.median(walls)
        results[name] = {
            "sim_seconds": SIM_SECONDS, "step_s": step_s, "substeps": substeps,
            "wall_best_s": best, "wall_median_s": med,
            "rtf_best": SIM_SECONDS / best, "rtf_median": SIM_SECONDS / med,
            "us_per_step_median": 1e6 * med / n, "compile_or_load_s": load_s,
        }
        print(f"{name:24s} rtf median {SIM_SECONDS / med:8.0f}x  best {SIM_SECONDS / best:8.0f}x  "
              f"{1e6 * med / n:6.2f} us/step  (compile/load {load_s:.2f} s)")
    target = 500.0
    ok = all(r["rtf_median"] >= target for r in results.values())
    print(f"target >= {target:.0f}x real time on one core: {'met' if ok else 'NOT met'}")
    out = {"benchmark": "finger_extensor_rtf", "target_rtf": target, "target_met": ok,
           "machine": platform.platform(), "python": platform.python_version(), "results": results}
    path = ROOT / "bench" / "results" / "finger_extensor_rtf.json"
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(out, indent=2))
    print(f"wrote {path}")
    return out


if __name__ == "__main__":
    main()
