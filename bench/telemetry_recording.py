"""Does a zenoh recording hold the whole session? ``record --from-zenoh`` started before, and some
seconds after, a ``rehab-hil run --device sim --lockstep --telemetry`` session (virtual time, about
real time here; ``--realtime`` for the device's own clock, which a loaded machine may trip), with
the publisher's history and recovery (this project's default) and without them (``--no-history``:
a plain subscriber, what every recording did before issue 41). Each recording's ``sample_index`` set is
compared with the session's own local recording (``run --record``); each prints where its missing
samples went. Prints the table, writes bench/results/telemetry_recording.json.

Everything is a separate process on loopback; the rig hosts the hub (the recorders started before it
wait for it). Target (issue 41): started before or 2 s after a 30 s session, every sample.
Usage: python bench/telemetry_recording.py [--seconds 30] [--late 2] [--device sim] [--realtime]
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[1]
RIG = "benchrec"
ENV = {**os.environ, "PYTHONPATH": str(ROOT / "src") + os.pathsep + os.environ.get("PYTHONPATH", "")}
CLI = [sys.executable, "-m", "rehab_hil.cli"]
# a recorder process that has imported everything and runs `rehab-hil record ...` when told (a line on
# stdin): its start is then when the bench says, not when a loaded machine gets its imports done
PRIMED = "import sys; from rehab_hil.cli import main; sys.stdin.readline(); sys.exit(main(sys.argv[1:]))"


def recorder(out: Path, port: int, history: bool, wait_s: float) -> subprocess.Popen[str]:
    """A primed ``rehab-hil record --from-zenoh`` process (``go`` starts it)."""
    cmd = ["record", "--from-zenoh", RIG, "--out", str(out), "--port", str(port), "--wait", str(wait_s)]
    return subprocess.Popen([sys.executable, "-c", PRIMED, *cmd, *([] if history else ["--no-history"])], env=ENV,
                            stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)


def go(p: subprocess.Popen[str]) -> None:
    assert p.stdin is not None
    p.stdin.write("\n")
    p.stdin.flush()


def first_batch_time(port: int, timeout_s: float) -> float:
    """When the rig's first state batch arrives (a plain client of the rig's hub, waiting for it)."""
    import zenoh

    from rehab_hil.telemetry.keys import RigKeys
    from rehab_hil.telemetry.session import NetworkConfig, open_session

    zenoh.init_log_from_env_or("error")
    first: list[float] = []
    session = open_session(NetworkConfig(port=port), wait_s=timeout_s)
    sub = session.declare_subscriber(RigKeys(RIG).state, lambda s: first or first.append(time.monotonic()))
    end = time.monotonic() + timeout_s
    while not first and time.monotonic() < end:
        time.sleep(0.01)
    sub.undeclare()
    session.close()
    if not first:
        raise SystemExit(f"no state batch from rig {RIG} within {timeout_s} s")
    return first[0]


def finish(p: subprocess.Popen[str]) -> list[str]:
    """The last lines a recorder printed (killed if it has not ended 120 s after the rig)."""
    try:
        out = p.communicate(timeout=120)[0]
    except subprocess.TimeoutExpired:
        p.kill()
        out = p.communicate()[0] + "\n(killed: still running 120 s after the rig ended)"
    return out.strip().splitlines()[-3:]


def indices(run_root: Path) -> tuple[set[int], dict[str, Any]]:
    """The sample_index set of the one run directory under ``run_root``, and its metadata."""
    from rehab_hil.interchange import read_csv

    (run_dir,) = [d for d in run_root.iterdir() if d.is_dir()]
    meta = json.loads((run_dir / "metadata.json").read_text())
    return {int(i) for i in read_csv(run_dir / "run.csv")["sample_index"]}, meta


def session(args: argparse.Namespace, tmp: Path, port: int) -> dict[str, Any]:
    """One session with four recorders: history/plain x started before/late."""
    procs: dict[str, subprocess.Popen[str]] = {}
    for when in ("before", "late"):
        for history in (True, False):
            procs[f"{'history' if history else 'plain'}_{when}"] = recorder(
                tmp / f"{history}_{when}", port, history, 300 if when == "before" else 30)
    time.sleep(5.0)  # imports done (a loaded machine is slow at them)
    for name in ("history_before", "plain_before"):
        go(procs[name])
    time.sleep(1.0)  # they are waiting for the hub
    lockstep = [] if args.realtime else ["--lockstep"]
    rig = subprocess.Popen([*CLI, "run", "--config", str(args.config), "--device", args.device, *lockstep,
                            "--duration", str(args.seconds), "--record", str(tmp / "local"), "--telemetry", RIG,
                            "--telemetry-port", str(port), "--no-display"], env=ENV, stdout=subprocess.PIPE,
                           stderr=subprocess.STDOUT, text=True)
    t_first = first_batch_time(port, 120)
    time.sleep(max(0.0, t_first + args.late - time.monotonic()))
    for name in ("history_late", "plain_late"):
        go(procs[name])
    rig_out, _ = rig.communicate(timeout=args.seconds + 300)
    said = {name: finish(p) for name, p in procs.items()}
    local, _ = indices(tmp / "local")
    rows = {}
    for name in procs:
        try:
            got, meta = indices(tmp / f"{name.startswith('history')}_{name.split('_')[1]}")
        except (OSError, ValueError):  # no run directory: it never saw the rig
            got, meta = set(), {}
        rows[name] = {"received": len(got & local), "local": len(local), "missing": len(local - got),
                      "extra": len(got - local), "equal": got == local, "lost": meta.get("lost"),
                      "accounting": meta.get("samples"), "said": said[name]}
    keep = ("cycles", "safety", "device time", "telemetry")  # how the session went (a trip ends it early)
    summary = [" ".join(line.strip("│ ").split()) for line in rig_out.splitlines() if any(k in line for k in keep)]
    return {"rig_summary": summary, "recordings": rows}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seconds", type=float, default=30.0, help="session length [s]")
    ap.add_argument("--late", type=float, default=2.0, help="late recorders start this long after the first sample")
    ap.add_argument("--device", default="sim", help="sim (default) or avr, or inprocess (always lockstep)")
    ap.add_argument("--realtime", action="store_true",
                    help="the device in real time (default: --lockstep, virtual time: no trip on a loaded machine)")
    ap.add_argument("--config", type=Path, default=ROOT / "configs" / "finger_extensor.toml")
    ap.add_argument("--out", type=Path, default=ROOT / "bench" / "results" / "telemetry_recording.json")
    args = ap.parse_args()
    from rehab_hil.testing import free_port

    with tempfile.TemporaryDirectory() as d:
        result = session(args, Path(d), free_port())
    result.update(setup={"seconds": args.seconds, "late_s": args.late, "device": args.device,
                         "lockstep": not args.realtime,
                         "config": str(args.config)}, load_avg_1min=os.getloadavg()[0])
    mode = "real time" if args.realtime else "--lockstep"
    print(f"{args.seconds:g} s session, --device {args.device} {mode}; rig: {' | '.join(result['rig_summary'])}")
    print(f"{'recording':34s} {'samples = local?':>22s}  missing  named (publisher/before joining/transit/writer)")
    names = {"history_before": "history, started before", "history_late": f"history, started {args.late:g} s after",
             "plain_before": "--no-history (as before), before", "plain_late": f"--no-history, {args.late:g} s after"}
    for key, label in names.items():
        r = result["recordings"][key]
        lost = r["lost"] or {}
        named = "/".join(str(lost.get(k)) for k in ("at_publisher", "before_joining", "in_transit", "in_writer"))
        print(f"{label:34s} {r['received']:>7d} of {r['local']:<7d} {'yes' if r['equal'] else 'NO':>4s}"
              f"  {r['missing']:7d}  {named}")
    for key, r in result["recordings"].items():
        if not r["accounting"]:
            print(f"  {names[key]}: {r['said'][-1] if r['said'] else 'no output'}")
    ok = result["recordings"]["history_before"]["equal"] and result["recordings"]["history_late"]["equal"]
    print(f"target (every sample, started before or {args.late:g} s after): {'met' if ok else 'NOT met'}")
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(result, indent=2) + "\n")
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
