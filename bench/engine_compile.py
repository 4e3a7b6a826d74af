"""What a new model structure costs to compile, to load, and how fast it then runs: this tree beside
another revision (default: the parent of the commit that split the engine into part modules).

Each figure is measured in a child process whose ``PYTHONPATH`` is the tree's ``src`` and whose
``REHAB_HIL_CACHE_DIR`` and ``NUMBA_CACHE_DIR`` start empty:

- first compile: the Finger Extensor plant on a clean machine (its part kernels and its engine);
- per structure: each further distinct structure of the same size (the plant plus a probe part whose
  wire gain differs), the cost the suite pays about 400 times; CPU seconds, the median of ``--structures``;
- load: a new process loading the compiled plant from the disk cache;
- speed: real-time factor of 60 s of the plant alone at 1 kHz (6 V step), of the plant under its PID
  (the ``cycle`` scenario) and of the SMA exoskeleton's plant over its ``session`` scenario (its wire's
  hysteresis solved every step), one core, the median of 5 runs; the two trees run interleaved
  ``--rounds`` times so that other work on the machine weighs on both alike. Each tree's SMA outputs are
  kept: the table says how far apart the two trees' numbers are (0: bit for bit the same).

Prints a table and writes bench/results/engine_compile.json.

    python bench/engine_compile.py                   # this tree beside the engine before the split
    python bench/engine_compile.py --against HEAD~3  # beside any revision
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
BEFORE_SPLIT = "32250d9"  # the engine that inlined every kernel into each structure's module
SIM_SECONDS = 60.0


def _structures(n: int, offset: int) -> list:
    """The Finger Extensor plant plus a probe ``Gain`` with wire gain 1 + i/7: distinct, same size."""
    from rehab_hil.loading import load_config
    from rehab_hil.models.sensors import Gain
    from rehab_hil.models.system import Diagram
    from rehab_hil.plants import get_plant

    cfg = load_config(ROOT / "configs" / "finger_extensor.toml")
    spec = get_plant("finger_extensor")
    out = []
    for i in range(offset, offset + n):
        probe = Gain("probe", connect={"u": [("iris_angle_rad", 1.0 + i / 7.0)]}, rename={"y": "probe"}, gain=1.0)
        out.append(Diagram([*spec.build(cfg), probe], inputs=("motor_voltage_v", "patient_torque_nm"),
                           sums=spec.ports(cfg).sums))
    return out


def _timed_compile(diagram, step_s: float) -> tuple[float, float]:
    """Wall and CPU seconds to compile (or load) ``diagram`` and run it for 10 steps."""
    w0, c0 = time.perf_counter(), time.process_time()
    diagram.compile(step_s, 1).simulate(10, {"motor_voltage_v": 1.0})
    return time.perf_counter() - w0, time.process_time() - c0


def child_compile(n: int) -> dict:
    """First compile on an empty cache, then ``n`` more structures (kernels now compiled)."""
    step_s = 1e-3
    first, *rest = _structures(n + 1, 0)
    wall0, cpu0 = _timed_compile(first, step_s)
    per = [_timed_compile(d, step_s) for d in rest]
    return {"first_wall_s": wall0, "first_cpu_s": cpu0,
            "per_structure_wall_s": statistics.median(w for w, _ in per),
            "per_structure_cpu_s": statistics.median(c for _, c in per)}


def child_load() -> dict:
    """The first structure again, in a new process: loaded from the disk cache."""
    wall, cpu = _timed_compile(_structures(1, 0)[0], 1e-3)
    return {"load_wall_s": wall, "load_cpu_s": cpu}


def child_speed() -> dict:
    """Real-time factor of the plant alone and under its PID, one core, median of 5 runs."""
    from rehab_hil.loading import load_config
    from rehab_hil.models.system import Diagram
    from rehab_hil.plants import get_plant

    os.sched_setaffinity(0, {min(os.sched_getaffinity(0))})
    cfg = load_config(ROOT / "configs" / "finger_extensor.toml")
    spec = get_plant("finger_extensor")
    step_s, substeps = spec.step(cfg)
    cycle = spec.scenarios["cycle"](cfg)
    cases = {"plant_rtf": (spec.build(cfg), {"motor_voltage_v": 6.0}, ()),
             "pid_cycle_rtf": ([*spec.build(cfg), *cycle.parts], dict(cycle.inputs), cycle.sums)}
    out = {}
    for name, (parts, inputs, sums) in cases.items():
        system = Diagram(parts, inputs=tuple(dict.fromkeys(("motor_voltage_v", "patient_torque_nm", *inputs))),
                         sums=(*spec.ports(cfg).sums, *sums)).compile(step_s, substeps)
        n = int(SIM_SECONDS / step_s)
        system.simulate(10, inputs)
        walls = []
        for _ in range(5):
            t0 = time.perf_counter()
            system.simulate(n, inputs)
            walls.append(time.perf_counter() - t0)
        out[name] = SIM_SECONDS / statistics.median(walls)
    return {**out, **_sma_speed()}


def _sma_speed() -> dict:
    """Real-time factor of the SMA exoskeleton's plant over its session scenario; its outputs kept beside the
    tree's cache (``_apart``)."""
    from rehab_hil.loading import load_config
    from rehab_hil.models.system import Diagram
    from rehab_hil.plants import get_plant

    cfg = load_config(ROOT / "configs" / "sma_exoskeleton.toml")
    spec = get_plant("sma_exoskeleton")
    sc = spec.scenarios["session"](cfg, duration_s=SIM_SECONDS)
    system = Diagram(spec.build(cfg), inputs=spec.inputs, sums=spec.ports(cfg).sums).compile(*spec.step(cfg))
    system.simulate(sc.n_steps, sc.inputs)  # compiled or loaded here, not in the first timed run
    walls = []
    for _ in range(5):
        t0 = time.perf_counter()
        res = system.simulate(sc.n_steps, sc.inputs, outputs=list(spec.outputs))
        walls.append(time.perf_counter() - t0)
    np.save(os.environ["REHAB_HIL_CACHE_DIR"] + "_sma_outputs.npy", np.column_stack([res[n] for n in spec.outputs]))
    return {"sma_rtf": SIM_SECONDS / statistics.median(walls)}


def _apart(a: np.ndarray, b: np.ndarray) -> float:
    """The largest difference of two runs' outputs, each column over its own range."""
    spread = np.ptp(a, axis=0)
    return float(np.max(np.abs(a - b) / np.where(spread > 0, spread, 1.0)))


def _run_child(src: Path, cache: Path, mode: str, n: int) -> dict:
    env = {**os.environ, "PYTHONPATH": str(src), "REHAB_HIL_CACHE_DIR": str(cache / "rh"),
           "NUMBA_CACHE_DIR": str(cache / "numba"), "OPENBLAS_NUM_THREADS": "1"}
    proc = subprocess.run([sys.executable, __file__, "--child", mode, "--structures", str(n)], env=env,
                          capture_output=True, text=True, check=True)
    return json.loads(proc.stdout.strip().splitlines()[-1])


def _export(rev: str, into: Path) -> Path:
    """The revision's ``src`` (``git archive``), to run the same measurement against."""
    tar = subprocess.run(["git", "-C", str(ROOT), "archive", rev, "src"], capture_output=True, check=True).stdout
    subprocess.run(["tar", "-x", "-C", str(into)], input=tar, check=True)
    return into / "src"


def measure(trees: dict[str, Path], n: int, rounds: int) -> dict[str, dict]:
    """Compile and load figures per tree, then the speed runs interleaved ``rounds`` times."""
    results: dict[str, dict] = {}
    with tempfile.TemporaryDirectory(prefix="engine_compile_") as tmp:
        for label, src in trees.items():
            cache = Path(tmp) / label
            results[label] = {**_run_child(src, cache, "compile", n), **_run_child(src, cache, "load", n)}
        speeds: dict[str, list[dict]] = {label: [] for label in trees}
        for _ in range(rounds):
            for label, src in trees.items():
                speeds[label].append(_run_child(src, Path(tmp) / label, "speed", n))
        outputs = [np.load(Path(tmp) / f"{label}" / "rh_sma_outputs.npy") for label in trees]
    for label, runs in speeds.items():
        for key in runs[0]:
            results[label][key] = statistics.median(r[key] for r in runs)
        results[label]["sma_apart"] = _apart(outputs[0], outputs[-1])
    return results


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--against", default=BEFORE_SPLIT, help="the revision to compare with (git)")
    ap.add_argument("--structures", type=int, default=6, help="distinct structures compiled after the first")
    ap.add_argument("--rounds", type=int, default=3, help="interleaved speed runs per tree")
    ap.add_argument("--child", choices=("compile", "load", "speed"), help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.child:
        fn = {"compile": lambda: child_compile(args.structures), "load": child_load, "speed": child_speed}
        print(json.dumps(fn[args.child]()))
        return
    with tempfile.TemporaryDirectory(prefix="engine_rev_") as rev_dir:
        trees = {"this tree": ROOT / "src", args.against: _export(args.against, Path(rev_dir))}
        results = measure(trees, args.structures, args.rounds)
    print(f"{'':12s} {'first compile':>18s} {'per structure':>18s} {'load':>8s} {'plant':>9s} {'plant+PID':>10s}"
          f" {'SMA plant':>10s}")
    for label, r in results.items():
        print(f"{label:12s} {r['first_wall_s']:6.1f} s ({r['first_cpu_s']:5.1f} cpu) "
              f"{r['per_structure_wall_s']:6.2f} s ({r['per_structure_cpu_s']:5.2f} cpu) {r['load_wall_s']:6.2f} s "
              f"{r['plant_rtf']:7.0f}x {r['pid_cycle_rtf']:9.0f}x {r['sma_rtf']:9.0f}x")
    apart = next(iter(results.values()))["sma_apart"]
    print("SMA outputs of the two trees: " + ("the same, bit for bit" if apart == 0.0 else
                                               f"at most {apart:.2g} of a channel's range apart"))
    print(f"load average {os.getloadavg()[0]:.1f} on {os.cpu_count()} cores (real-time factors: one core, 1 kHz)")
    out = {"benchmark": "engine_compile", "against": args.against, "structures": args.structures,
           "rounds": args.rounds, "load_average": os.getloadavg()[0], "results": results}
    path = ROOT / "bench" / "results" / "engine_compile.json"
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(out, indent=2))
    print(f"wrote {path}")


if __name__ == "__main__":
    main()
