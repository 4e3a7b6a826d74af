"""What the loop achieves over the Uno's link (issue 16): both simulated devices, direct pty vs the
16U2 USB-bridge model (devices/usb_bridge.py; optionally with jitter). Per case:

- loop: reaction (sample arrival -> command written) p50/p99, command -> echo latency p50/p99
  (host clock), samples per loop cycle (burst size) mean/max, arrival gap p99/max, missed cycles;
- device side, in device time: the longest gap between two applied COMMANDs (what the firmware
  watchdog must tolerate);
- safety timing: the heating-time trip's device time against its configured limit (target: within
  2 % under bursty arrival), PWM off after a host stall (device time after the last applied
  command, against the watchdog), and (Python device) link loss detected after the device falls
  silent (host time after the last sample).

Prints a table and writes bench/results/link_timing.json. Usage:
python bench/link_timing.py [--duration 10] [--devices sim,avr] [--jitter-ms 2]
"""

from __future__ import annotations

import argparse
import dataclasses
import itertools
import json
import os
import platform
import tempfile
import threading
import time
from pathlib import Path
from typing import Any

import numpy as np

from rehab_hil.hardware import Arrival, open_rig
from rehab_hil.loading import load_config
from rehab_hil.loop.estimation import State
from rehab_hil.loop.records import EventRecord
from rehab_hil.plants import get_plant
from rehab_hil.protocol import Fault, Sample
from rehab_hil.service import assembly
from rehab_hil.service.session import open_session
from rehab_hil.testing import push_runtime

ROOT = Path(__file__).resolve().parents[1]
CONFIG = ROOT / "configs" / "finger_extensor.toml"


def link_config(tmp: Path, bridge: bool, jitter_ms: float) -> Path:
    """The plant config with ``[rig.link]`` switched as wanted (the spawners read it)."""
    text = CONFIG.read_text()
    text = text.replace("usb_bridge = false", f"usb_bridge = {'true' if bridge else 'false'}")
    text = text.replace("jitter_ms = 0.0", f"jitter_ms = {jitter_ms}")
    path = tmp / f"fe_{'bridge' if bridge else 'direct'}_{jitter_ms:g}.toml"
    path.write_text(text)
    return path


class Tap:
    """Wraps the hardware's ``read`` (the loop's) to keep every sample and its arrival (the runner's view)."""

    def __init__(self, hw: Any) -> None:
        self.hw, self.samples, self.arrivals, self.burst = hw, [], [], []
        self._read = hw.read
        hw.read = self.read

    def read(self, timeout: float | None = None) -> Arrival | None:
        a = self._read(timeout)
        if a is not None:
            self.samples.append(a.sample)
            self.arrivals.append(a.host_time_s)
        return a


def applied_command_gaps_ms(samples: list[Sample]) -> float:
    """Longest device-time gap between two samples whose cmd_seq_echo changed (a new COMMAND applied)."""
    times = [s.device_time_us for a, s in itertools.pairwise(samples) if s.cmd_seq_echo != a.cmd_seq_echo]
    return float(np.max(np.diff(times)) / 1000.0) if len(times) > 1 else float("nan")


def session(kind: str, config: Path, duration_s: float) -> dict[str, Any]:
    cfg = load_config(config)
    binding = get_plant(cfg.plant).device(cfg)
    conf = dataclasses.replace(assembly.firmware_configure(cfg, binding), watchdog_ms=1000)
    with open_rig(kind, config, connect_timeout_s=15.0) as hw:
        tap = Tap(hw)
        sup = assembly.build_supervisor(cfg, binding)
        sup.limits = dataclasses.replace(sup.limits, link_loss_periods=1000)  # measure, do not stop
        with open_session(config, hw=hw, configure=conf, supervisor=sup, realtime=True) as rig:  # [rig.session]
            res = rig.run(duration_s)
    gaps = np.diff(tap.arrivals) * 1e3 if len(tap.arrivals) > 1 else np.array([np.nan])
    return {
        "stop_reason": res.stop_reason, "cycles": res.cycles, "samples": res.samples,
        "samples_per_cycle_mean": res.samples / max(res.cycles, 1),
        "reaction_p50_us": res.reaction.get("lateness_p50_us", float("nan")),
        "reaction_p99_us": res.reaction.get("lateness_p99_us", float("nan")),
        "cmd_echo_p50_ms": 1e3 * res.link.get("latency_p50_s", float("nan")),
        "cmd_echo_p99_ms": 1e3 * res.link.get("latency_p99_s", float("nan")),
        "arrival_gap_p99_ms": float(np.percentile(gaps, 99)), "arrival_gap_max_ms": float(np.max(gaps)),
        "missed_pct": res.timing.get("missed_pct", float("nan")), "sample_gaps": res.sample_gaps,
        "device_max_command_gap_ms": applied_command_gaps_ms(tap.samples),
    }


def heating_trip(kind: str, config: Path, limit_s: float = 2.0) -> dict[str, Any]:
    """Open-loop drive until the host's heating-time trip; its device time against the limit."""
    cfg = load_config(config)
    binding = get_plant(cfg.plant).device(cfg)
    conf = dataclasses.replace(assembly.firmware_configure(cfg, binding), watchdog_ms=1000,
                               max_heating_ms=int(1000 * (limit_s + 5)))
    with open_rig(kind, config, connect_timeout_s=15.0) as hw:
        sup = assembly.build_supervisor(cfg, binding)
        sup.limits = dataclasses.replace(sup.limits, max_heating_s=limit_s, link_loss_periods=1000)
        ctl = push_runtime(cfg, 0.05, 100.0, 0.0)
        with open_session(config, hw=hw, controller=ctl, configure=conf, supervisor=sup, realtime=True) as rig:
            t0 = time.perf_counter()
            res = rig.run(limit_s + 3.0)
            wall = time.perf_counter() - t0
    ev = res.events[0] if res.events else None
    t = ev.t_s if ev is not None and ev.reason == "heating_time" else float("nan")
    return {"limit_s": limit_s, "trip_device_s": t, "error_pct": 100.0 * (t - limit_s) / limit_s,
            "reason": ev.reason if ev else "none", "wall_s": wall, "cycles": res.cycles, "samples": res.samples}


class Stall:
    """A controller that pauses the host loop once (a GC / scheduler stall) at ``at_s``."""

    def __init__(self, inner: Any, at_s: float, pause_s: float) -> None:
        self.inner, self.at_s, self.pause_s, self.done = inner, at_s, pause_s, False
        self.claims = getattr(inner, "claims", None)

    def reset(self) -> None:
        self.inner.reset()

    def __call__(self, t_s: float, state: State) -> Any:
        if not self.done and t_s >= self.at_s:
            self.done = True
            time.sleep(self.pause_s)
        return self.inner(t_s, state)


def host_stall(kind: str, config: Path, watchdog_ms: int = 100, pause_s: float = 0.5) -> dict[str, Any]:
    """The host pauses ``pause_s``: the firmware's watchdog must cut PWM; measured in device time
    from the samples the host reads afterwards."""
    cfg = load_config(config)
    binding = get_plant(cfg.plant).device(cfg)
    conf = dataclasses.replace(assembly.firmware_configure(cfg, binding), watchdog_ms=watchdog_ms)
    with open_rig(kind, config, connect_timeout_s=15.0) as hw:
        tap = Tap(hw)
        sup = assembly.build_supervisor(cfg, binding)
        sup.limits = dataclasses.replace(sup.limits, link_loss_periods=5000)
        ctl = Stall(push_runtime(cfg, 0.05, 100.0, 0.0), 0.5, pause_s)
        with open_session(config, hw=hw, controller=ctl, configure=conf, supervisor=sup, realtime=True) as rig:
            res = rig.run(2.0)
    last_cmd_us, off_us = None, None
    for a, s in itertools.pairwise(tap.samples):
        if s.faults & Fault.WATCHDOG:
            off_us = s.device_time_us if s.duty0 == 0 else None
            break
        if s.cmd_seq_echo != a.cmd_seq_echo:
            last_cmd_us = s.device_time_us
    on_ms = (off_us - last_cmd_us) / 1000.0 if off_us is not None and last_cmd_us is not None else float("nan")
    return {"watchdog_ms": watchdog_ms, "pause_s": pause_s, "pwm_on_after_last_command_ms": on_ms,
            "host_trip": res.events[0].reason if res.events else "none"}


class TripClock:
    """A loop sink that notes the host time the loop hands over its first safety event."""

    name, critical, dropped, error, on_failure = "trip-clock", False, 0, None, None

    def __init__(self) -> None:
        self.at: list[float] = []

    def offer(self, record: Any) -> bool:
        if type(record) is EventRecord and not self.at:
            self.at.append(time.perf_counter())
        return True

    def wake(self) -> None:
        pass

    def drain(self) -> None:
        pass

    def close(self) -> None:
        pass


def link_loss(kind: str, config: Path) -> dict[str, Any]:
    """The device falls silent (Python device's ``stall`` knob): host time to the link_loss trip."""
    if kind != "sim":
        return {}
    cfg = load_config(config)
    binding = get_plant(cfg.plant).device(cfg)
    from rehab_hil.devices import spawn_device
    from rehab_hil.hardware import SerialHardware

    dev = spawn_device("sim", config)
    hw = SerialHardware(dev.port, write_timeout_s=2.0)
    try:
        hw.connect(timeout=15.0)
        tap = Tap(hw)
        sup = assembly.build_supervisor(cfg, binding)
        clock = TripClock()
        with open_session(config, hw=hw, supervisor=sup, sinks=(clock,), realtime=True) as rig:  # [rig.session]
            tripped = clock.at
            threading.Timer(1.0, dev.control, args=("stall 3000",)).start()
            res = rig.run(5.0)
        ev = res.events[0] if res.events else None
        detection = float("nan")
        if ev is not None and ev.reason == "link_loss" and tripped:
            detection = 1e3 * (tripped[0] - tap.arrivals[-1])
    finally:
        hw.close()
        dev.close()
    return {"budget_ms": sup.limits.link_loss_periods * assembly.period_s(cfg) * 1e3,
            "reason": ev.reason if ev else "none", "detected_after_last_sample_ms": detection}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--duration", type=float, default=10.0, help="session length per case [s]")
    ap.add_argument("--devices", default="sim,avr")
    ap.add_argument("--jitter-ms", type=float, default=2.0, help="the jittered bridge case's jitter [ms]")
    ap.add_argument("--out", type=Path, default=ROOT / "bench" / "results" / "link_timing.json")
    args = ap.parse_args()
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        links = [("direct", False, 0.0), ("usb-bridge", True, 0.0), (f"usb-bridge+{args.jitter_ms:g}ms", True,
                                                                       args.jitter_ms)]
        for kind in args.devices.split(","):
            for name, bridge, jitter in links:
                config = link_config(Path(tmp), bridge, jitter)
                row = {"device": kind, "link": name, "session": session(kind, config, args.duration),
                       "heating": heating_trip(kind, config), "host_stall": host_stall(kind, config),
                       "link_loss": link_loss(kind, config)}
                rows.append(row)
                s, h, w, ll = row["session"], row["heating"], row["host_stall"], row["link_loss"]
                print(f"{kind:4s} {name:18s} reaction p50/p99 {s['reaction_p50_us']:.0f}/{s['reaction_p99_us']:.0f} us"
                      f" | cmd->echo p50/p99 {s['cmd_echo_p50_ms']:.2f}/{s['cmd_echo_p99_ms']:.2f} ms"
                      f" | samples/cycle {s['samples_per_cycle_mean']:.2f} | arrival gap p99/max "
                      f"{s['arrival_gap_p99_ms']:.1f}/{s['arrival_gap_max_ms']:.1f} ms | missed {s['missed_pct']:.2f} %"
                      f" | device cmd gap max {s['device_max_command_gap_ms']:.1f} ms"
                      f" | heating trip {h['trip_device_s']:.3f} s ({h['error_pct']:+.2f} %)"
                      f" | PWM on after last cmd (wd {w['watchdog_ms']} ms) {w['pwm_on_after_last_command_ms']:.1f} ms"
                      + (f" | link loss after {ll['detected_after_last_sample_ms']:.0f} ms (budget "
                         f"{ll['budget_ms']:.0f})" if ll else ""), flush=True)
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps({"machine": platform.platform(), "load_avg": os.getloadavg(), "rows": rows},
                                   indent=2, default=float))
    print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
