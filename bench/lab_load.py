"""Lab load on loopback: N simulated rigs at 1 kHz through one ``rehab-hil router`` to 2 subscribers.

Every rig, every subscriber and the router is its own process, as in a lab. A rig process is a
zenoh client session with the real ``TelemetryPublisher`` fed by a 1 kHz pacing thread with the
loop's two records per cycle (a sample record and a command record, as ``LoopService`` hands them),
not a full control loop (8 real loops do not fit on 2 cores beside the rest). A subscriber process
subscribes to ``rehab/*/state``, decodes every batch and notes its arrival. Figures over a measuring
window after a warm-up: records delivered per second to each subscriber (of N x 2000 offered),
drops (batches missing in transit + records dropped at the publishers), end-to-end latency of the
newest record of each batch (p50/p99; ``time.perf_counter`` is CLOCK_MONOTONIC, shared by processes),
and the router's CPU (utime + stime from /proc over the window). Prints the table, writes
bench/results/lab_load.json.

Usage: python bench/lab_load.py [--rigs 1,2,4,8] [--warmup 2] [--seconds 8]
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
PY = sys.executable


# -- rig process ------------------------------------------------------------------------------------
def rig(ep: str, rig_id: str, seconds: float) -> None:
    """Publish 1 kHz cycles (sample + command record) for ``seconds`` after 'go' on stdin."""
    import zenoh

    from rehab_hil.loop.controllers import Command
    from rehab_hil.loop.estimation import State
    from rehab_hil.loop.records import CommandRecord, SampleRecord
    from rehab_hil.protocol import Sample
    from rehab_hil.telemetry import NetworkConfig, TelemetryPublisher, open_session

    zenoh.init_log_from_env_or("error")
    session = open_session(NetworkConfig(mode="lab", router=(ep,)))
    pub = TelemetryPublisher(session, rig_id, queue_size=20_000)
    end = time.monotonic() + 30
    while not pub.has_subscribers() and time.monotonic() < end:
        time.sleep(0.01)
    print("ready", flush=True)
    sys.stdin.readline()  # go
    period = 1e-3
    t0 = time.perf_counter()
    n = 0
    late = 0
    while True:
        deadline = t0 + n * period
        now = time.perf_counter()
        if now < deadline:
            time.sleep(deadline - now)
        elif now - deadline > period:  # skip missed ticks (don't catch up), count them
            skipped = int((now - deadline) / period)
            n += skipped
            late += skipped
            continue
        if deadline - t0 >= seconds:
            break
        ts = time.perf_counter()
        cmd = Command((0.3, 0.0), 0, True, 30.0 + n % 100)
        pub.offer(SampleRecord(ts, n * period, Sample(n * 1000, n, n % 4000, 512, 0, 300, 0, 0, 0, 0, n, 0),
                               State(n * period, 0.5, 0.1, {"drive_torque_nm": 0.01 * (n % 50)}), cmd, n, 30.0))
        pub.offer(CommandRecord(ts, n * period, cmd, n + 1, 30.0))
        n += 1
    pub.close()
    session.close()
    print(json.dumps({"rig": rig_id, "cycles": n - late, "skipped_ticks": late, "offered": pub.offered,
                      "dropped": pub.dropped, "published": pub.published_samples}), flush=True)


# -- subscriber process -----------------------------------------------------------------------------
def subscriber(ep: str) -> None:
    """Note (arrival, rig, batch_seq, records, newest host time, dropped_total) of every state batch."""
    import zenoh

    from rehab_hil.telemetry import NetworkConfig, decode_state, open_session
    from rehab_hil.telemetry.keys import rig_from_key

    zenoh.init_log_from_env_or("error")
    session = open_session(NetworkConfig(mode="lab", router=(ep,)))
    rows: list[tuple[float, str, int, int, float, int]] = []

    def on_put(zs: Any) -> None:
        now = time.perf_counter()
        b = decode_state(zs.payload.to_bytes())
        rows.append((now, rig_from_key(str(zs.key_expr)), b.batch_seq, len(b.samples), b.samples[-1].host_time_s,
                     b.dropped_total))

    sub = session.declare_subscriber("rehab/*/state", on_put)
    cpu0 = os.times()
    print("ready", flush=True)
    t0, t1 = (float(x) for x in sys.stdin.readline().split())
    sub.undeclare()
    cpu1 = os.times()
    session.close()
    lat, records, missing, dropped = [], 0, 0, {}
    last: dict[str, int] = {}
    for now, rid, seq, count, newest, drop in rows:
        if rid in last and seq != last[rid] + 1:
            missing += seq - last[rid] - 1
        last[rid] = seq
        dropped[rid] = drop
        if t0 <= now < t1:
            records += count
            lat.append(now - newest)
    a = np.array(lat) if lat else np.array([np.nan])
    print(json.dumps({"records_per_s": records / (t1 - t0), "missing_batches": missing,
                      "publisher_dropped": sum(dropped.values()), "rigs_seen": len(last),
                      "latency_p50_ms": 1e3 * float(np.percentile(a, 50)),
                      "latency_p99_ms": 1e3 * float(np.percentile(a, 99)),
                      "cpu_s": (cpu1.user + cpu1.system) - (cpu0.user + cpu0.system)}), flush=True)


# -- orchestration ----------------------------------------------------------------------------------
def _spawn(*args: str) -> subprocess.Popen[str]:
    return subprocess.Popen([PY, __file__, *args], stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True,
                            cwd=ROOT)


def _proc_cpu_s(pid: int) -> float:
    fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


def measure(n: int, warmup: float, seconds: float) -> dict[str, Any]:
    from rehab_hil.testing import free_port

    ep = f"tcp/127.0.0.1:{free_port()}"
    router = subprocess.Popen([PY, "-m", "rehab_hil.cli", "router", "--listen", ep], stdout=subprocess.PIPE, text=True,
                              cwd=ROOT)
    assert router.stdout is not None and router.stdout.readline().startswith("zenoh router listening")
    subs = [_spawn("--role", "sub", "--ep", ep) for _ in range(2)]
    for s in subs:
        assert s.stdout is not None and s.stdout.readline().strip() == "ready"
    rigs = [_spawn("--role", "rig", "--ep", ep, "--rig", f"rig{i}", "--seconds", str(warmup + seconds))
            for i in range(n)]
    for r in rigs:
        assert r.stdout is not None and r.stdout.readline().strip() == "ready"
    load0 = os.getloadavg()[0]
    go = time.perf_counter()
    for r in rigs:
        assert r.stdin is not None
        r.stdin.write("go\n")
        r.stdin.flush()
    t0, t1 = go + warmup, go + warmup + seconds
    time.sleep(max(0.0, t0 - time.perf_counter()))
    cpu0 = _proc_cpu_s(router.pid)
    time.sleep(max(0.0, t1 - time.perf_counter()))
    router_cpu = (_proc_cpu_s(router.pid) - cpu0) / seconds
    rig_out = [json.loads(r.communicate(timeout=60)[0].strip().splitlines()[-1]) for r in rigs]
    time.sleep(0.3)
    sub_out = []
    for s in subs:
        sub_out.append(json.loads(s.communicate(f"{t0} {t1}\n", timeout=60)[0].strip().splitlines()[-1]))
    router.terminate()
    router.communicate(timeout=20)
    return {"rigs": n, "offered_records_per_s": sum(r["cycles"] for r in rig_out) * 2 / (warmup + seconds),
            "rig_skipped_ticks": sum(r["skipped_ticks"] for r in rig_out),
            "publisher_dropped": sum(r["dropped"] for r in rig_out), "subscribers": sub_out,
            "router_cpu_pct": 100 * router_cpu, "load_avg_1min_at_start": load0}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--role", choices=("main", "rig", "sub"), default="main")
    ap.add_argument("--ep")
    ap.add_argument("--rig")
    ap.add_argument("--seconds", type=float, default=8.0)
    ap.add_argument("--warmup", type=float, default=2.0)
    ap.add_argument("--rigs", default="1,2,4,8")
    a = ap.parse_args()
    if a.role == "rig":
        return rig(a.ep, a.rig, a.seconds)
    if a.role == "sub":
        return subscriber(a.ep)
    results = []
    print(f"{'rigs':>4} {'offered rec/s':>13} {'delivered rec/s (sub1/sub2)':>28} {'drops (transit/pub)':>20} "
          f"{'latency p50/p99 ms':>19} {'router CPU':>10} {'load':>5}")
    for n in (int(x) for x in a.rigs.split(",")):
        r = measure(n, a.warmup, a.seconds)
        results.append(r)
        s = r["subscribers"]
        lat = f"{max(x['latency_p50_ms'] for x in s):.1f} / {max(x['latency_p99_ms'] for x in s):.1f}"
        drops = f"{sum(x['missing_batches'] for x in s)}b / {r['publisher_dropped']}"
        print(f"{n:>4} {r['offered_records_per_s']:>13.0f} "
              f"{s[0]['records_per_s']:>13.0f} / {s[1]['records_per_s']:<12.0f} {drops:>20} {lat:>19} "
              f"{r['router_cpu_pct']:>9.0f}% {r['load_avg_1min_at_start']:>5.1f}", flush=True)
    out = ROOT / "bench" / "results" / "lab_load.json"
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps({"host": platform.node(), "cpus": os.cpu_count(), "date": time.strftime("%Y-%m-%d"),
                               "warmup_s": a.warmup, "seconds": a.seconds, "results": results}, indent=2) + "\n")
    print(f"wrote {out.relative_to(ROOT)}")


if __name__ == "__main__":
    main()
