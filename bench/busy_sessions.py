"""Real-time simulated sessions on a busy machine: does any trip that the host did not cause remain?

Issue 41's target: N real-time sessions of D s each, ``--parallel`` at a time, ``--device sim`` and
``--device avr`` alternating, with ``--busy`` busy loops (``sh -c 'while :; do :; done'``) beside
them. Each session is the real CLI (``rehab-hil run --no-display --record DIR``) in its own process;
its metadata.json gives the stop reason, every trip with its cause (``loop/trip_cause.py``), the
stalls the device reported of its own process and the silences the host excused because the device
process could not run. A trip whose cause is not "host stall" counts against the target.

With ``--views`` each session also runs what a lab runs beside it: zenoh telemetry (its own loopback
port) and the live twin (issue 46's target: no trip, no recorder or telemetry drop). The drops of every
sink (the recorder, zenoh, the twin, and the loop process's ring) are read from metadata.json.

Prints one line per session, then the counts. Usage:
  python bench/busy_sessions.py [--sessions 20] [--duration 20] [--parallel 2] [--busy 2] [--views]
                                [--config configs/finger_extensor.toml] [--devices sim,avr] [--tree DIR]
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
BUSY = ["sh", "-c", "while :; do :; done"]


def start_session(i: int, kind: str, args: argparse.Namespace, out: Path) -> tuple[subprocess.Popen, Path]:
    """One ``rehab-hil run`` in its own process, recording into ``out/<i>``."""
    folder = out / f"{i:02d}-{kind}"
    folder.mkdir(parents=True)
    env = {**os.environ, "PYTHONPATH": str(args.tree / "src")}
    argv = [sys.executable, "-m", "rehab_hil.cli", "run", "--config", str(args.config), "--device", kind,
            "--duration", str(args.duration), "--no-display", "--record", str(folder), "--rig-id", f"s{i}"]
    if args.views:
        argv += ["--twin", "--telemetry", f"s{i}", "--telemetry-port", str(7600 + i)]
    log = (folder / "stdout.txt").open("w")
    proc = subprocess.Popen(argv, stdin=subprocess.DEVNULL, stdout=log, stderr=subprocess.STDOUT, env=env,
                            cwd=str(args.tree))
    log.close()
    return proc, folder


def read_session(i: int, kind: str, folder: Path, rc: int) -> dict[str, Any]:
    """The figures of one finished session from its metadata.json (or why there are none)."""
    metas = sorted(folder.glob("*/metadata.json"))
    if not metas:
        tail = (folder / "stdout.txt").read_text(errors="replace").strip().splitlines()[-3:]
        return {"i": i, "device": kind, "rc": rc, "error": " | ".join(tail)}
    m = json.loads(metas[-1].read_text())
    stalls = m.get("stalls") or {}
    rep = stalls.get("device_reported") or {}
    events = m.get("safety_events", [])
    return {"i": i, "device": kind, "rc": rc, "stop": m.get("stop_reason", "?"),
            "events": [{"reason": e["reason"], "t_s": e["t_s"], "detail": e["detail"], "cause": e.get("cause", "")}
                       for e in events],
            "device_stalls": int(rep.get("not_scheduled", 0)),
            "device_stall_max_ms": rep.get("not_scheduled_max_ms", 0.0),
            "excused_silences": len(stalls.get("device_silences_not_scheduled") or []),
            "reaction_p99_us": (m.get("timing") or {}).get("lateness_p99_us", float("nan")),
            "drops": {k: int(v.get("dropped", 0)) for k, v in (m.get("sinks") or {}).items()},
            "pwm_off_at_end": m.get("pwm_off_at_end")}


def host_caused(ev: dict[str, Any]) -> bool:
    return ev["cause"].startswith("host stall")


def line(r: dict[str, Any]) -> str:
    if "error" in r:
        return f"{r['i']:2d} {r['device']:4s} no result (rc {r['rc']}): {r['error']}"
    trip = "; ".join(f"{e['reason']} {e['detail']} at {e['t_s']:.2f} s -> {e['cause'][:110] or 'no cause given'}"
                     for e in r["events"][:1]) or "no trip"
    return (f"{r['i']:2d} {r['device']:4s} {trip} | device stalls {r['device_stalls']} (longest "
            f"{r['device_stall_max_ms']:.0f} ms), silences excused {r['excused_silences']}, reaction p99 "
            f"{r['reaction_p99_us']:.0f} us, drops {r['drops']}, PWM off {r['pwm_off_at_end']}")


def run_all(args: argparse.Namespace, out: Path) -> tuple[list[dict[str, Any]], list[float]]:
    kinds = args.devices.split(",")
    results: list[dict[str, Any]] = []
    loads: list[float] = []
    for start in range(0, args.sessions, args.parallel):
        batch = [(i, kinds[i % len(kinds)]) for i in range(start, min(start + args.parallel, args.sessions))]
        running = [(i, k, *start_session(i, k, args, out)) for i, k in batch]
        while any(p.poll() is None for _, _, p, _ in running):
            loads.append(os.getloadavg()[0])
            time.sleep(1.0)
        for i, k, p, folder in running:
            r = read_session(i, k, folder, p.returncode)
            results.append(r)
            print(line(r), flush=True)
    return results, loads


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sessions", type=int, default=20)
    ap.add_argument("--duration", type=float, default=20.0)
    ap.add_argument("--parallel", type=int, default=2)
    ap.add_argument("--busy", type=int, default=2, help="busy loops beside the sessions")
    ap.add_argument("--config", type=Path, default=ROOT / "configs" / "finger_extensor.toml")
    ap.add_argument("--devices", default="sim,avr", help="device kinds, alternating")
    ap.add_argument("--keep", type=Path, default=None, help="write the sessions' folders here (kept)")
    ap.add_argument("--views", action="store_true", help="zenoh telemetry and the live twin in every session")
    ap.add_argument("--tree", type=Path, default=ROOT, help="the checkout whose src/ runs the sessions (the "
                    "alternative: an older tree, e.g. before issue 41; its trips carry no cause)")
    args = ap.parse_args()
    busy = [subprocess.Popen(BUSY) for _ in range(args.busy)]
    print(f"{args.sessions} sessions x {args.duration:g} s, {args.parallel} at a time, devices {args.devices}, "
          f"{args.busy} busy loops, {os.cpu_count()} CPUs, config {args.config.name}, tree {args.tree}", flush=True)
    try:
        with tempfile.TemporaryDirectory(prefix="busy_sessions-") as tmp:
            results, loads = run_all(args, args.keep or Path(tmp))
    finally:
        for p in busy:
            p.kill()
            p.wait()
    trips = [(r, e) for r in results if "error" not in r for e in r["events"][:1]]
    host = [t for t in trips if host_caused(t[1])]
    print(f"\nload average (1 min) during the run: median {sorted(loads)[len(loads) // 2]:.1f}, max {max(loads):.1f}")
    print(f"sessions {len(results)}, without a result {sum('error' in r for r in results)}, trips {len(trips)}: "
          f"{len(host)} caused by the host, {len(trips) - len(host)} not caused by the host (target: 0)")
    for r, e in trips:
        print(f"  session {r['i']} ({r['device']}): {e['reason']} {e['detail']}: {e['cause'] or 'no cause given'}")
    drops = sum(sum(r.get("drops", {}).values()) for r in results)
    print(f"records dropped by any sink (recorder, zenoh, twin, ring): {drops} (target: 0)")
    print(f"device stalls reported (not faults): {sum(r.get('device_stalls', 0) for r in results)}, longest "
          f"{max((r.get('device_stall_max_ms', 0.0) for r in results), default=0.0):.0f} ms; link silences "
          f"excused as device stalls: {sum(r.get('excused_silences', 0) for r in results)}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
