"""The learning on the rig's cost to the loop thread (issue 39: the loop's reaction must not grow).

A loaded 2-core machine trips ``bench/loop_reaction.py``'s real-time sessions on link loss before
the first update (13.9 s), with and without the learning; this bench isolates what the learning
adds on the loop's thread. The shipped SMA controller (``ControllerRuntime``) is stepped as the
loop steps it, ``__call__`` (sample -> command: the reaction path) then ``advance`` (after the
write), one call per 1 ms of device time for 150 s of device time, as fast as it goes, with the
learning on (its worker thread computing an update each cycle meanwhile, never waited for) and
off. Prints the per-call percentiles of each path and the worker's time per update.
Usage: python bench/rig_learning_step.py [--device-s 150]
"""

from __future__ import annotations

import argparse
import gc
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]


def run(learning: bool, device_s: float) -> dict[str, float]:
    from rehab_hil.loading import load_config
    from rehab_hil.loop.estimation import State
    from rehab_hil.service import assembly
    from rehab_hil.service.rig_learning import RigLearning, TableStore

    cfg = load_config(ROOT / "configs" / "sma_exoskeleton.toml")
    rt = assembly.build_controller(cfg)
    ref = rt.reference
    learn = None
    if learning:
        spec = rt.controller.rig_learning
        with tempfile.TemporaryDirectory() as tmp:
            store = TableStore(Path(tmp), "bench", None, spec.plan_key)
            learn = RigLearning(spec, next(iter(rt.controller.plan.signals.values())), store, lockstep=False)
        learn.store = None
        rt.learn_on_rig(learn)
    n = round(device_s * 1000)
    t_call, t_adv = np.empty(n), np.empty(n)
    angle = ref.values(np.arange(n) * 1e-3) * 0.9  # the finger 10 % short: an error to learn from
    gc.collect()
    gc.freeze()
    sys.setswitchinterval(0.0005)  # as realtime_setup does for the loop
    pc = time.perf_counter
    for k in range(n):
        t = k * 1e-3
        a = pc()
        rt(t, State(t, float(angle[k]), 0.0, {}))
        b = pc()
        rt.advance()
        t_call[k], t_adv[k] = b - a, pc() - b
    gc.unfreeze()
    out = {"updates": float(len(learn.log)) if learn else 0.0, "late": float(learn.late) if learn else 0.0}
    for name, v in (("call", t_call), ("advance", t_adv)):
        for q in (50, 99, 99.9):
            out[f"{name}_p{q}_us"] = float(np.percentile(v, q) * 1e6)
        out[f"{name}_max_us"] = float(v.max() * 1e6)
    if learn:
        learn.close()
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--device-s", type=float, default=150.0)
    args = ap.parse_args()
    for learning in (False, True, False, True):
        r = run(learning, args.device_s)
        print(f"learning {'on ' if learning else 'off'}  " + "  ".join(f"{k} {v:.1f}" for k, v in r.items()),
              flush=True)
    from rehab_hil.controllers.rig_learning import RigLearner  # the update alone, on this thread
    from rehab_hil.loading import load_config
    from rehab_hil.service import assembly

    rt = assembly.build_controller(load_config(ROOT / "configs" / "sma_exoskeleton.toml"))
    spec, table = rt.controller.rig_learning, next(iter(rt.controller.plan.signals.values()))
    learner = RigLearner(spec, table)
    learner.prepare()
    times = []
    for err in (0.5, 5.0, 30.0):  # within the budget, and one that the budget scales back
        t0 = time.perf_counter()
        learner.update(table, np.full(spec.n, err), np.clip(table, *spec.bounds))
        times.append((time.perf_counter() - t0) * 1e3)
    print("one update [ms] (error 0.5 / 5 / 30 deg):", " / ".join(f"{x:.1f}" for x in times))


if __name__ == "__main__":
    main()
