"""Serial link figures for each simulated device: host -> device -> host round trip and sustained rate.

For each device (Python device in real time and in lockstep; the firmware in simavr when built):
- ``command_echo``: send a COMMAND, wait for the first SAMPLE echoing its seq (p50/p99/max; in
  real time this includes waiting for the next 1 kHz sample tick);
- ``heartbeat``: HEARTBEAT -> HEARTBEAT, the link and the device's frame handling only;
- ``sustained``: the loop's pattern (read a SAMPLE, answer with a COMMAND) for a few seconds at
  1 kHz: samples per wall second, samples per device second, dropped samples, bad frames.
Frames are protocol v1 at 1 Mbaud sizes (SAMPLE 37 B, COMMAND 14 B on the wire; a pty ignores baud).
Prints the figures and writes bench/results/serial_roundtrip.json.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import time
from pathlib import Path
from typing import Any

import numpy as np

from rehab_hil.devices import spawn_device
from rehab_hil.hardware import SerialHardware
from rehab_hil.protocol import CommandFrame, Configure

ROOT = Path(__file__).resolve().parents[1]
CONFIG = ROOT / "configs" / "finger_extensor.toml"
WIDE = 1 << 30
OPEN = Configure(1000, 60_000, 10000, 600_000, 1023, -WIDE, WIDE, 0)  # watchdog 60 s: phases pause


def _pct(values: list[float]) -> dict[str, float]:
    a = np.asarray(values) * 1e3
    return {"n": len(a), "p50_ms": float(np.percentile(a, 50)), "p99_ms": float(np.percentile(a, 99)),
            "max_ms": float(a.max())}


def command_echo(hw: SerialHardware, n: int) -> dict[str, float]:
    lat = []
    for _ in range(n):
        hw.discard_pending()
        t0 = time.perf_counter()
        seq = hw.send_command(CommandFrame(0, 0, 0, 1))
        for _ in range(5000):
            s = hw.read_sample(1.0)
            if s is None:
                raise RuntimeError("device stopped streaming")
            if s.cmd_seq_echo == seq:
                break
        else:
            raise RuntimeError(f"COMMAND {seq} never applied (faults {s.faults:#x})")
        lat.append(hw.last_sample_time - t0)
    return _pct(lat)


def heartbeat(hw: SerialHardware, n: int) -> dict[str, float]:
    lat = []
    for _ in range(n):
        t0 = time.perf_counter()
        hw.heartbeat()
        lat.append(time.perf_counter() - t0)
    return _pct(lat)


def sustained(hw: SerialHardware, seconds: float) -> dict[str, float]:
    hw.discard_pending()
    dropped0, bad0 = hw.stats.dropped_samples, hw.stats.bad_frames.total()
    first = hw.read_sample(1.0)
    if first is None:
        hw.send_command(CommandFrame(0, 0, 0, 1))  # lockstep: the first COMMAND starts the exchange
        first = hw.read_sample(1.0)
    t0, n, last = time.perf_counter(), 0, first
    while time.perf_counter() - t0 < seconds:
        hw.send_command(CommandFrame(0, 0, 0, 1))
        s = hw.read_sample(1.0)
        if s is None:
            raise RuntimeError("device stopped streaming")
        n, last = n + 1, s
    wall = time.perf_counter() - t0
    device_s = (last.device_time_us - first.device_time_us) / 1e6
    return {"wall_s": wall, "samples": n, "samples_per_wall_s": n / wall,
            "samples_per_device_s": n / device_s if device_s > 0 else float("nan"),
            "device_s_per_wall_s": device_s / wall,
            "dropped_samples": hw.stats.dropped_samples - dropped0,
            "host_bad_frames": hw.stats.bad_frames.total() - bad0}


def run_device(kind: str, clock: str, n: int, seconds: float) -> dict[str, Any]:
    t0 = time.perf_counter()
    with spawn_device(kind, CONFIG, clock=clock) as dev:
        startup = time.perf_counter() - t0
        with SerialHardware(dev.port) as hw:
            hw.connect(timeout=10.0)
            hw.configure(OPEN)
            if not hw.clear():
                raise RuntimeError("device has a fault that does not clear")
            hw.send_command(CommandFrame(0, 0, 0, 1))
            out: dict[str, Any] = {"startup_s": startup}
            out["heartbeat"] = heartbeat(hw, n // 2)
            out["command_echo"] = command_echo(hw, n)
            out["sustained"] = sustained(hw, seconds)
            return out


def main(argv: list[str] | None = None) -> dict[str, Any]:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n", type=int, default=2000, help="round trips per figure")
    ap.add_argument("--seconds", type=float, default=5.0, help="duration of the sustained run [s]")
    ap.add_argument("--devices", default="python/realtime,python/lockstep,avr/realtime")
    args = ap.parse_args(argv)
    results: dict[str, Any] = {"machine": {"cpus": os.cpu_count(), "python": platform.python_version(),
                                           "platform": platform.platform()},
                               "time_utc": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()), "devices": {}}
    for item in args.devices.split(","):
        kind, clock = item.split("/")
        if kind == "avr":
            from rehab_hil.devices import avr_device

            reason = avr_device.unavailable_reason()
            if reason:
                print(f"{item:18s} skipped: {reason}")
                results["devices"][item] = {"skipped": reason}
                continue
        r = run_device(kind, clock, args.n, args.seconds)
        results["devices"][item] = r
        ce, hb, su = r["command_echo"], r["heartbeat"], r["sustained"]
        print(f"{item:18s} command->echo p50 {ce['p50_ms']:6.3f} ms  p99 {ce['p99_ms']:6.3f} ms | "
              f"heartbeat p50 {hb['p50_ms']:6.3f} ms  p99 {hb['p99_ms']:6.3f} ms | "
              f"sustained {su['samples_per_wall_s']:7.0f} samples/s (device {su['samples_per_device_s']:.0f}/s, "
              f"dropped {su['dropped_samples']}, bad {su['host_bad_frames']}) | startup {r['startup_s']:.1f} s")
    out = ROOT / "bench" / "results" / "serial_roundtrip.json"
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(results, indent=2) + "\n")
    print(f"wrote {out.relative_to(ROOT)}")
    return results


if __name__ == "__main__":
    main()
