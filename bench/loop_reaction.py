"""Reaction of the loop (sample in -> command out) with recording and zenoh telemetry on, through
the real Python simulated device on a pty in real time: today's path and the path before issue 25,
side by side in one run, direct and behind the USB-bridge link model (``[rig.link]``).

"Before" is the loop as it was at commit ``BASE`` (``git archive`` of its ``src/`` into a temporary
directory, imported in a child process through PYTHONPATH); "after" is this tree. Everything else
is the same for both: the device process (this tree's, spawned here, SCHED_FIFO 5), the plant
config and its session controller, a ``Recorder`` writing CSV + MCAP, a ``RigTelemetry`` zenoh
publisher with a subscriber in this process receiving every batch, the loop at SCHED_FIFO 10 with
the GC frozen (as ``rehab-hil run`` does on a real rig). Runs alternate before/after so that a change
in the machine's load falls on both. ``--bare`` adds this tree without recording and telemetry: the
floor a loop in a process of its own (recorder and publisher elsewhere) could reach. ``--display``
adds ``rehab-hil run``'s live display (rich, 4 Hz) to every run.

Per run: the runner's reaction p50 / p99 / p99.9 / max (from the moment its read returned to the
write), the same from the sample's device tick (includes waiting to be scheduled and for the GIL,
the pty and the device's own lateness; see ``Tap``), missed cycles (samples not controlled:
coalesced or lost), command -> echo, drops, records received by a zenoh subscriber, the 1-minute
load average.

Targets (issue 25): reaction p99 <= 150 us, max <= 1 ms, missed <= 0.1 % (direct link); issue 46 (the loop
in a process of its own, ``--twin``: recording, zenoh and the twin on): p99 <= 100 us, missed <= 0.05 %, max
<= 1 ms. Since issue 46 the loop runs in another process than the bench's child, whose ``Tap`` then sees no
sample: the device tick -> command column is empty for "after" (the runner's reaction is the loop's own).
Prints a table and writes bench/results/loop_reaction.json. Usage:
python bench/loop_reaction.py [--duration 30] [--repeats 3] [--links direct,bridge] [--bare] [--display]
[--base COMMIT]
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import resource
import statistics
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[1]
BASE = "32250d9"  # the last commit before issue 46 (the loop in a process of its own): "before"
CONFIG = ROOT / "configs" / "sma_exoskeleton.toml"  # `make run`'s rig


# ---- the child: one session on a device that is already running ---------------------------------
def child(args: argparse.Namespace) -> int:
    """One session against the pty ``args.port`` with whatever ``rehab_hil`` PYTHONPATH gives."""
    import importlib.util

    import rehab_hil
    from rehab_hil.hardware.serial_hw import SerialHardware

    builder = importlib.util.find_spec("rehab_hil.service.session") is not None  # issue 37's open_session
    cfg, conf, period_s = _child_config(args)
    hw = SerialHardware(args.port, cfg.rig.baud)
    hw.connect(timeout=20.0)  # behind the bridge: the DTR reset and ~1 s of bootloader first
    tap = Tap(hw, round(args.duration / period_s) + 100)
    with tempfile.TemporaryDirectory() as rec_dir:
        run, progress, close = (_child_session if builder else _child_loop)(args, cfg, conf, hw, rec_dir)
        print("READY", flush=True)  # the parent's subscriber connects now
        sys.stdin.readline()  # ... and says when it is subscribed
        stop_display = threading.Event()
        if args.display:  # rehab-hil run's live display: a rich table redrawn 4 times a second
            threading.Thread(target=display, args=(progress, stop_display), daemon=True).start()
        r0, t0 = _cpu(), time.perf_counter()
        res = run()
        r1, t1 = _cpu(), time.perf_counter()
        stop_display.set()
        rows, offered = close()
        hw.close()
    cpu = (r1 - r0) / (t1 - t0)
    t = res.timing
    out = {
        "rehab_hil": str(Path(rehab_hil.__file__).parent), "stop_reason": res.stop_reason,
        "scheduler": res.realtime.scheduler if res.realtime else "", "cycles": res.cycles, "samples": res.samples,
        "process": getattr(res.realtime, "process", "") if res.realtime else "",
        "sample_gaps": res.sample_gaps, "missed_cycles": t.get("missed_cycles"), "missed_pct": t.get("missed_pct"),
        "reaction_us": {q: res.reaction.get(f"lateness_{q}_us") for q in ("p50", "p99", "p99_9", "max")},
        "tick_to_command_us": tap.tick_to_command(),
        "cmd_echo_us": {q: 1e6 * res.link.get(f"latency_{q}_s", float("nan")) for q in ("p50", "p99")},
        "recorder_rows": rows, "recorder_dropped": res.recorder_dropped,
        "telemetry_dropped": res.telemetry_dropped, "telemetry_offered": offered,
        "host_cpu_pct": 100.0 * cpu, "events": [e.reason for e in res.events],
    }
    print("RESULT " + json.dumps(out), flush=True)
    return 0


def _cpu() -> float:
    """CPU seconds of this process and its finished children (a loop process of its own is one)."""
    a, b = resource.getrusage(resource.RUSAGE_SELF), resource.getrusage(resource.RUSAGE_CHILDREN)
    return a.ru_utime + a.ru_stime + b.ru_utime + b.ru_stime


def _child_config(args: argparse.Namespace) -> tuple[Any, Any, float]:
    """The config, the CONFIGURE (``--watchdog-ms`` over the config's) and the period, in either tree."""
    import dataclasses

    from rehab_hil.plants import get_plant
    from rehab_hil.service import assembly

    try:
        from rehab_hil.loading import load_config
    except ImportError:  # the tree before issue 37
        from rehab_hil.plants import load_config
    cfg = load_config(args.config)
    conf = assembly.firmware_configure(cfg, get_plant(cfg.plant).device(cfg))
    if args.watchdog_ms:
        conf = dataclasses.replace(conf, watchdog_ms=args.watchdog_ms)
    return cfg, conf, assembly.period_s(cfg)


def _child_session(args: argparse.Namespace, cfg: Any, conf: Any, hw: Any, rec_dir: str) -> tuple[Any, Any, Any]:
    """This tree: the session from ``open_session`` on the connected rig, recording and publishing."""
    from rehab_hil.service.session import TelemetryOptions, open_session

    extra = {} if args.bare else {"record": Path(rec_dir), "twin": args.twin,
                                  "telemetry": TelemetryOptions("bench", port=args.zenoh_port)}
    session = open_session(args.config, hw=hw, configure=conf, realtime=True, **extra)

    def close() -> tuple[int, int]:
        session.close()
        if hasattr(session, "feature"):  # issue 46: the session's features
            rec, tel = session.feature("recording"), session.feature("telemetry")
            return (rec.recorder.rows if rec else 0), (tel.sink.offered if tel else 0)
        rec, tel = session.recorder, session.telemetry
        return (rec.rows if rec else 0), (tel.sink.offered if tel else 0)

    return (lambda: session.run(args.duration)), (lambda: session.progress), close


def _child_loop(args: argparse.Namespace, cfg: Any, conf: Any, hw: Any, rec_dir: str) -> tuple[Any, Any, Any]:
    """The tree before issue 37: the loop wired by hand as its ``rehab-hil run`` did."""
    from rehab_hil.loop.recorder import Recorder
    from rehab_hil.loop.runner import LoopService
    from rehab_hil.plants import get_plant
    from rehab_hil.service import assembly
    from rehab_hil.telemetry import NetworkConfig
    from rehab_hil.telemetry.rig import RigTelemetry, rig_info

    binding = get_plant(cfg.plant).device(cfg)
    controller = assembly.build_controller(cfg, source=str(args.config))
    recorder = tel = None
    if not args.bare:
        recorder = Recorder(rec_dir, binding)
        tel = RigTelemetry("bench", rig_info(cfg.plant, args.config, binding, assembly.period_s(cfg), hw.info),
                           NetworkConfig(role="hub", port=args.zenoh_port), queue_size=20_000)
    svc = LoopService(hw, conf, controller, assembly.build_estimator(cfg, binding),
                      assembly.build_supervisor(cfg, binding), assembly.period_s(cfg),
                      recorder=recorder, telemetry=tel.sink if tel else None,
                      meter=assembly.build_meter(cfg, controller, args.duration))
    if tel is not None:
        tel.watch(svc, hw)

    def close() -> tuple[int, int]:
        if tel is not None:
            tel.close()
        if recorder is not None:
            recorder.close()
        return (recorder.rows if recorder else 0), (tel.sink.offered if tel else 0)

    return (lambda: svc.run(args.duration, pacing="device", realtime=True)), (lambda: svc.progress), close


def display(progress: Any, stop: threading.Event) -> None:
    """What ``rehab-hil run`` does on its main thread while the loop runs: rich's Live, 4 Hz."""
    import io

    from rich.console import Console
    from rich.live import Live

    from rehab_hil.cli.run import _progress_table

    console = Console(file=io.StringIO(), force_terminal=True, width=100)
    with Live(_progress_table(progress()), console=console, refresh_per_second=4) as live:
        while not stop.wait(0.25):
            live.update(_progress_table(progress()))


class Tap:
    """Wraps the hardware's read_sample and write_command (the runner calls them on the instance)
    to keep, for each command written after a new sample, that sample's device time, its arrival
    and the write (preallocated; a few hundred ns a cycle, the same for every path)."""

    def __init__(self, hw: Any, n: int) -> None:
        import numpy as np

        self.rows = np.zeros((n, 3))
        self.k = 0
        self.dev_us: int | None = None
        self.arrival = 0.0
        write = hw.write_command

        if hasattr(hw, "read"):  # since issue 37 the loop reads (arrival, sample, gap)
            read = hw.read

            def read_arrival(timeout: float | None = None) -> Any:
                a = read(timeout)
                if a is not None:
                    self.dev_us, self.arrival = a.sample.device_time_us, a.host_time_s
                return a

            hw.read = read_arrival
        else:
            read_sample_of = hw.read_sample

            def read_sample(timeout: float | None = None) -> Any:
                s = read_sample_of(timeout)
                if s is not None:
                    self.dev_us, self.arrival = s.device_time_us, hw.last_sample_time
                return s

            hw.read_sample = read_sample

        def write_command(*a: Any, **kw: Any) -> int:
            seq = write(*a, **kw)
            now = time.perf_counter()
            if self.dev_us is not None and self.k < len(self.rows):
                self.rows[self.k] = (self.dev_us * 1e-6, self.arrival, now)
                self.k += 1
                self.dev_us = None
            return seq

        hw.write_command = write_command

    def tick_to_command(self) -> dict[str, float]:
        """Each controlled sample's device tick (its device time on the host's monotonic clock: the
        constant offset taken as the smallest arrival - device time within +-1000 samples, which
        follows the device's rare re-anchoring after a stall) to its command's write. Unlike the
        runner's reaction (from the moment its read returned) this includes the time the sample
        waited for the loop thread to be scheduled and to get the GIL, the pty's delivery and the
        device's own lateness in sending it."""
        import numpy as np

        if self.k < 10:
            return {q: float("nan") for q in ("p50", "p99", "p99_9", "max")}
        d, a, w = self.rows[: self.k].T
        half = min(1000, self.k // 2)
        padded = np.pad(a - d, half, mode="edge")
        offset = np.lib.stride_tricks.sliding_window_view(padded, 2 * half + 1).min(axis=1)
        x = (w - d - offset) * 1e6
        return {"p50": float(np.percentile(x, 50)), "p99": float(np.percentile(x, 99)),
                "p99_9": float(np.percentile(x, 99.9)), "max": float(x.max())}


# ---- the parent: devices, subscribers, the before/after runs ----------------------------------------
def link_config(tmp: Path, config: Path, bridge: bool, base: str | None = None) -> Path:
    """``config`` with ``[rig.link] usb_bridge`` switched as wanted (the device spawner reads it);
    with ``base``, the config as it was at that commit (the older loop refuses keys added since,
    e.g. ``[twin]``)."""
    text = config.read_text()
    if base is not None and config.resolve().is_relative_to(ROOT):
        rel = config.resolve().relative_to(ROOT).as_posix()
        text = subprocess.run(["git", "-C", str(ROOT), "show", f"{base}:{rel}"], check=True, capture_output=True,
                              text=True).stdout
    if "usb_bridge = false" not in text:
        raise SystemExit(f"{config}: no '[rig.link] usb_bridge = false' line to switch")
    path = tmp / f"{config.stem}_{'bridge' if bridge else 'direct'}{'_' + base if base else ''}.toml"
    path.write_text(text.replace("usb_bridge = false", f"usb_bridge = {'true' if bridge else 'false'}"))
    return path


def base_tree(tmp: Path, base: str) -> Path:
    """``src/`` of commit ``base``, unpacked under ``tmp``."""
    dest = tmp / f"base-{base}"
    dest.mkdir()
    archive = subprocess.run(["git", "-C", str(ROOT), "archive", base, "src"], check=True, capture_output=True).stdout
    subprocess.run(["tar", "-x", "-C", str(dest)], input=archive, check=True)
    return dest / "src"


class Counting:
    """A zenoh subscriber to the bench rig that counts what it receives (telemetry really flows)."""

    def __init__(self, port: int) -> None:
        from rehab_hil.telemetry import NetworkConfig
        from rehab_hil.telemetry.session import TelemetryConfigError, open_session
        from rehab_hil.telemetry.subscriber import subscribe

        for _ in range(200):
            try:
                self.session = open_session(NetworkConfig(port=port))
                break
            except TelemetryConfigError:
                time.sleep(0.05)
        else:
            raise RuntimeError(f"no zenoh hub on port {port}")
        self.received = 0
        self.sub = subscribe("bench", self._on, session=self.session)

    def _on(self, s: Any) -> None:
        self.received += 1

    def close(self) -> None:
        self.sub.close()
        self.session.close()


def one_run(variant: str, src: Path, config: Path, bridge: bool, args: argparse.Namespace) -> dict[str, Any]:
    from rehab_hil.devices import spawn_device
    from rehab_hil.testing import free_port

    port = free_port()
    load_before = os.getloadavg()[0]
    dev = spawn_device("sim", config, clock="realtime")
    try:
        env = {**os.environ, "PYTHONPATH": str(src)}
        cmd = [sys.executable, str(Path(__file__).resolve()), "--child", "--port", dev.port, "--config", str(config),
               "--duration", str(args.duration), "--zenoh-port", str(port)]
        if args.watchdog_ms:
            cmd += ["--watchdog-ms", str(args.watchdog_ms)]
        if args.display:
            cmd += ["--display"]
        if args.twin:
            cmd += ["--twin"]
        if variant == "bare":
            cmd += ["--bare"]
        proc = subprocess.Popen(cmd, env=env, stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True)
        assert proc.stdin is not None and proc.stdout is not None
        result: dict[str, Any] = {}
        sub = None
        lines: list[str] = []

        def read() -> None:
            for line in proc.stdout:  # type: ignore[union-attr]
                lines.append(line)

        reader = threading.Thread(target=read, daemon=True)
        reader.start()
        try:
            while not any(x.startswith("READY") for x in lines):
                if proc.poll() is not None:
                    raise RuntimeError(f"{variant} child ended before READY: {''.join(lines)[-2000:]}")
                time.sleep(0.02)
            if variant != "bare":
                sub = Counting(port)
                time.sleep(0.5)  # the subscription is declared at the hub
            proc.stdin.write("go\n")
            proc.stdin.flush()
            proc.wait(timeout=args.duration + 120)
            reader.join(5)
        finally:
            if proc.poll() is None:
                proc.kill()
            if sub is not None:
                sub.close()
        for line in lines:
            if line.startswith("RESULT "):
                result = json.loads(line[len("RESULT "):])
        if not result:
            raise RuntimeError(f"{variant} child gave no result (exit {proc.returncode}): {''.join(lines)[-2000:]}")
        result["telemetry_received"] = sub.received if sub is not None else 0
    finally:
        dev.close()
    result.update({"variant": variant, "link": "usb_bridge" if bridge else "direct", "duration_s": args.duration,
                   "load_avg_1min_before": load_before, "load_avg_1min_after": os.getloadavg()[0]})
    return result


def row(r: dict[str, Any]) -> str:
    x, y = r["reaction_us"], r["tick_to_command_us"]
    return (f"| {r['variant']} | {r['link']} | {x['p50']:.0f} / {x['p99']:.0f} / {x['p99_9']:.0f} / {x['max']:.0f} | "
            f"{y['p50']:.0f} / {y['p99']:.0f} / {y['p99_9']:.0f} / {y['max']:.0f} | "
            f"{r['missed_pct']:.3f} % ({r['missed_cycles']:.0f}) | {r['cmd_echo_us']['p50']:.0f} / "
            f"{r['cmd_echo_us']['p99']:.0f} | {r['host_cpu_pct']:.0f} % | {r['recorder_dropped']} / "
            f"{r['telemetry_dropped']} | {r['telemetry_received']} | {r['load_avg_1min_before']:.2f} | "
            f"{r['stop_reason']} |")


HEADER = ("| path | link | reaction p50 / p99 / p99.9 / max [us] | device tick -> command p50 / p99 / p99.9 / max [us] "
          "| missed cycles | cmd -> echo p50 / p99 [us] | loop CPU | recorder / telemetry drops | records received "
          "over zenoh | load (1 min) | end |\n"
          "| --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- |")


def summary(runs: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """Per path and link: median and range over the repeats."""
    out = []
    for variant in ("before", "after", "bare"):
        for link in ("direct", "usb_bridge"):
            sel = [r for r in runs if r["variant"] == variant and r["link"] == link]
            if not sel:
                continue
            agg: dict[str, Any] = {"variant": variant, "link": link, "runs": len(sel)}
            for q in ("p50", "p99", "p99_9", "max"):
                v = [r["reaction_us"][q] for r in sel]
                agg[f"reaction_{q}_us"] = {"median": statistics.median(v), "min": min(v), "max": max(v)}
                v = [r["tick_to_command_us"][q] for r in sel]
                agg[f"tick_{q}_us"] = {"median": statistics.median(v), "min": min(v), "max": max(v)}
            v = [r["missed_pct"] for r in sel]
            agg["missed_pct"] = {"median": statistics.median(v), "min": min(v), "max": max(v)}
            out.append(agg)
    return out


def summary_row(a: dict[str, Any]) -> str:
    def f(k: str, fmt: str = ".0f") -> str:
        d = a[k]
        return f"{d['median']:{fmt}} ({d['min']:{fmt}}-{d['max']:{fmt}})"

    return (f"| {a['variant']} | {a['link']} | {a['runs']} | {f('reaction_p50_us')} | {f('reaction_p99_us')} | "
            f"{f('reaction_p99_9_us')} | {f('reaction_max_us')} | {f('tick_p99_us')} | {f('tick_max_us')} | "
            f"{f('missed_pct', '.3f')} |")


SUMMARY_HEADER = ("| path | link | runs | reaction p50 [us] | p99 | p99.9 | max | tick -> command p99 | max | "
                  "missed cycles [%] |\n| --- | --- | --- | --- | --- | --- | --- | --- | --- | --- |")


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--duration", type=float, default=30.0, help="seconds per session")
    ap.add_argument("--repeats", type=int, default=3, help="before/after pairs per link")
    ap.add_argument("--links", default="direct,bridge", help="comma-separated: direct, bridge")
    ap.add_argument("--config", type=Path, default=CONFIG)
    ap.add_argument("--base", default=BASE, help="the commit whose loop is 'before'")
    ap.add_argument("--watchdog-ms", type=int, default=None, help="override the firmware watchdog")
    ap.add_argument("--display", action="store_true", help="with rehab-hil run's live display (rich, 4 Hz)")
    ap.add_argument("--twin", action="store_true", help="the live twin beside the rig too (issue 46's target)")
    ap.add_argument("--bare", action="store_true", help="also 'bare': this tree without recording and telemetry "
                    "(the floor for a loop in a process of its own)")
    ap.add_argument("--out", type=Path, default=ROOT / "bench" / "results" / "loop_reaction.json")
    ap.add_argument("--child", action="store_true", help=argparse.SUPPRESS)
    ap.add_argument("--port", help=argparse.SUPPRESS)
    ap.add_argument("--zenoh-port", type=int, help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.child:
        return child(args)
    links = [x.strip() for x in args.links.split(",") if x.strip()]
    if not set(links) <= {"direct", "bridge"}:
        raise SystemExit("--links: direct, bridge")
    runs: list[dict[str, Any]] = []
    with tempfile.TemporaryDirectory() as tmp_s:
        tmp = Path(tmp_s)
        trees = {"before": base_tree(tmp, args.base), "after": ROOT / "src", "bare": ROOT / "src"}
        variants = ("before", "after", "bare") if args.bare else ("before", "after")
        configs = {(v, link): link_config(tmp, args.config, link == "bridge", args.base if v == "before" else None)
                   for v in variants for link in links}
        uptime_start = subprocess.run(["uptime"], capture_output=True, text=True).stdout.strip()
        print(f"uptime at start: {uptime_start}", flush=True)
        print(HEADER, flush=True)
        for i in range(args.repeats):
            for link in links:
                order = variants if i % 2 == 0 else variants[::-1]
                for variant in order:
                    r = one_run(variant, trees[variant], configs[variant, link], link == "bridge", args)
                    r["repeat"] = i
                    runs.append(r)
                    print(row(r), flush=True)
        uptime_end = subprocess.run(["uptime"], capture_output=True, text=True).stdout.strip()
    agg = summary(runs)
    print(f"\nuptime at end: {uptime_end}\n\n{SUMMARY_HEADER}")
    for a in agg:
        print(summary_row(a))
    head = subprocess.run(["git", "-C", str(ROOT), "rev-parse", "--short", "HEAD"], capture_output=True,
                          text=True).stdout.strip()
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps({
        "machine": platform.platform(), "cpus": os.cpu_count(), "python": platform.python_version(),
        "config": str(args.config.relative_to(ROOT) if args.config.is_relative_to(ROOT) else args.config),
        "before_commit": args.base, "after_commit": head, "duration_s": args.duration, "repeats": args.repeats,
        "display": args.display,
        "uptime_start": uptime_start, "uptime_end": uptime_end, "summary": agg, "runs": runs,
    }, indent=2))
    print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
