"""Real-time factor of the full coupled SMA exoskeleton (seed 000) at a 1 kHz step (target >= 100x
on one core), the per-sample cost of the stepper the rig uses, and a batch of 100 parameter
variations run on one compiled system (only ``params=`` changes).

Prints the figures and writes bench/results/sma_exoskeleton_rtf.json. Compilation is excluded
(once per diagram structure, cached on disk) and reported separately.
"""

from __future__ import annotations

import json
import os
import platform
import statistics
import time
from pathlib import Path

import numpy as np

from rehab_hil.loading import load_config
from rehab_hil.models.system import Diagram
from rehab_hil.plants import get_plant

ROOT = Path(__file__).resolve().parents[1]
SIM_SECONDS = 30.0
REPEATS = 5
BATCH = 100
BATCH_SECONDS = 10.0
TARGET = 100.0


def main() -> dict:
    os.sched_setaffinity(0, {min(os.sched_getaffinity(0))})  # one core
    cfg = load_config(ROOT / "configs" / "sma_exoskeleton.toml")
    spec = get_plant("sma_exoskeleton")
    step_s, substeps = spec.step(cfg)
    t0 = time.perf_counter()
    diagram = Diagram(spec.build(cfg), inputs=("pwm_duty", "supply_voltage_v"), sums=spec.ports(cfg).sums)
    system = diagram.compile(step_s, substeps)
    system.simulate(10, {"pwm_duty": 1.0, "supply_voltage_v": 32.0})
    load_s = time.perf_counter() - t0

    # a session: 5 bends a minute (heat 5 s, cool 7 s), the canonical outputs recorded
    sc = spec.scenarios["session"](cfg, duration_s=SIM_SECONDS)
    walls, cpus = [], []
    for _ in range(REPEATS):
        t1, c1 = time.perf_counter(), time.process_time()
        system.simulate(sc.n_steps, sc.inputs, outputs=list(spec.outputs))
        walls.append(time.perf_counter() - t1)
        cpus.append(time.process_time() - c1)
    med, best = statistics.median(walls), min(walls)
    cpu_med = statistics.median(cpus)  # CPU time: what the run costs when the core is shared

    stepper = system.stepper(outputs=list(spec.outputs))
    u = np.array([1.0 if n == "pwm_duty" else 32.0 for n in system.input_names])
    n_step = 5000
    stepper.step(u)  # the first call compiles the step function for these array types
    t1 = time.perf_counter()
    for _ in range(n_step):
        stepper.step(u)
    stepper_us = 1e6 * (time.perf_counter() - t1) / n_step

    # 100 variations (+-20 %) of the contact stiffness k, the wire prestrain and the convection h1
    rng = np.random.default_rng(0)
    names = ["pad.stiffness_n_per_m", "contact.stiffness_n_per_m", "sma_active.prestrain",
             "sma_thermal.h1_w_per_m2_c"]
    idx = [diagram.param_index(n) for n in names]
    n_batch = round(BATCH_SECONDS / step_s)
    duty = np.where(np.arange(n_batch) * step_s < 5.0, 1.0, 0.0)
    peaks = []
    t1 = time.perf_counter()
    for _ in range(BATCH):
        p = system.params.copy()
        scale = rng.uniform(0.8, 1.2, 3)
        p[idx[0]] *= scale[0]
        p[idx[1]] *= scale[0]  # the pad and the force part share k
        p[idx[2]] *= scale[1]
        p[idx[3]] *= scale[2]
        res = system.simulate(n_batch, {"pwm_duty": duty, "supply_voltage_v": 32.0},
                              outputs=["theta_mcp_deg"], params=p)
        peaks.append(float(res["theta_mcp_deg"].max()))
    batch_s = time.perf_counter() - t1

    rtf_med = SIM_SECONDS / med
    ok = rtf_med >= TARGET
    results = {
        "session_run": {"sim_seconds": SIM_SECONDS, "step_s": step_s, "substeps": substeps,
                        "wall_median_s": med, "wall_best_s": best, "rtf_median": rtf_med,
                        "rtf_best": SIM_SECONDS / best, "us_per_step_median": 1e6 * med / sc.n_steps,
                        "cpu_median_s": cpu_med, "rtf_cpu_median": SIM_SECONDS / cpu_med,
                        "load_average_1min": os.getloadavg()[0]},
        "stepper_us_per_step": stepper_us,
        "batch": {"variations": BATCH, "sim_seconds_each": BATCH_SECONDS, "wall_s": batch_s,
                  "rtf": BATCH * BATCH_SECONDS / batch_s, "mcp_peak_deg_min": min(peaks),
                  "mcp_peak_deg_max": max(peaks)},
        "compile_or_load_s": load_s,
    }
    print(f"session run     rtf median {rtf_med:8.0f}x  best {SIM_SECONDS / best:8.0f}x  "
          f"{1e6 * med / sc.n_steps:6.2f} us/step  (compile/load {load_s:.2f} s)")
    print(f"                rtf on CPU time {SIM_SECONDS / cpu_med:8.0f}x  "
          f"(load average {os.getloadavg()[0]:.1f}: wall time includes waiting for the shared core)")
    print(f"stepper         {stepper_us:6.2f} us/step (Python call per sample, as the simulated rig does)")
    print(f"batch of {BATCH}    {batch_s:.2f} s wall for {BATCH} x {BATCH_SECONDS:.0f} s "
          f"(rtf {BATCH * BATCH_SECONDS / batch_s:.0f}x); MCP peak {min(peaks):.1f}..{max(peaks):.1f} deg")
    ok_cpu = SIM_SECONDS / cpu_med >= TARGET
    print(f"target >= {TARGET:.0f}x real time on one core: wall {'met' if ok else 'NOT met'}, "
          f"CPU time {'met' if ok_cpu else 'NOT met'}")
    out = {"benchmark": "sma_exoskeleton_rtf", "target_rtf": TARGET, "target_met": ok, "target_met_cpu": ok_cpu,
           "machine": platform.platform(), "python": platform.python_version(), "results": results}
    path = ROOT / "bench" / "results" / "sma_exoskeleton_rtf.json"
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(out, indent=2))
    print(f"wrote {path}")
    return out


if __name__ == "__main__":
    main()
