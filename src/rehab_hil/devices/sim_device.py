"""The Python simulated device: a process that owns a pty, speaks protocol v1 like the firmware
and closes the loop with a plant model.

Run: ``python -m sim_devices.python_device --config configs/finger_extensor.toml
[--clock realtime|lockstep] [--drop P] [--corrupt P] [--delay-ms D] [--adc-noise-counts S]``.
The first stdout line is the pty's slave path. Clocks: ``realtime`` ticks at 1 kHz on absolute
wall-clock deadlines (late ticks are caught up, never skipped: device time is tick count);
``lockstep`` advances one sample period (k base ticks, one SAMPLE) per valid COMMAND while
streaming, deterministic and as fast as the host goes. An accepted CONFIGURE starts the session
clock of the plant's scheduled changes (``PlantIO.start_session``; docs/models.md).

Control channel (stdin, one command per line; each answered by one stdout line ``ok ...`` or
``error ...``); stdin closing ends the process:

  estop 0|1          e-stop button released/pressed (the pin level follows the config's [rig.estop] wiring)
  estop_wire ok|broken  the e-stop loop's wire intact / cut (a cut loop reads high: a stop when normally closed)
  input NAME VALUE   set a constant plant input (e.g. patient_torque_nm 0.5)
  drop P             drop each outgoing frame with probability P
  corrupt P          flip one byte of each outgoing frame with probability P
  delay MS           hold every outgoing frame MS milliseconds
  garbage N          write N random bytes now
  truncate           cut the next outgoing frame in half (still delimited)
  stall MS           send nothing for MS milliseconds of device time (frames meant for then are lost)
  disconnect         close the pty and exit
  reboot [CAUSE]     reset the device (seq 0, unconfigured, HELLO sent); CAUSE: external|watchdog
  status             one line of counters (with the device's own stalls: not_scheduled=N ..._total_ms ..._max_ms,
                     and ..._excused_ms: the ticks it caught up that its watchdog did not count)

A realtime device measures its own stalls (``devices/stall.py``): when its process was not
scheduled for ``STALL_MIN_S`` or more and the host's commands arrived meanwhile, the ticks it then
catches up do not count towards its watchdog (an MCU is never descheduled: it would have seen those
commands in time); it logs each stall on stderr and counts them in ``status``. When nothing arrived
meanwhile the watchdog counts them as ever: a stalled host still trips it.
"""

from __future__ import annotations

import argparse
import errno
import os
import random
import select
import sys
import termios
import time
import tty
from collections.abc import Sequence
from typing import Any, TextIO

from rehab_hil.devices.control import UNKNOWN, ControlChannel
from rehab_hil.devices.core import DeviceCore, Readings
from rehab_hil.devices.plant_io import PlantIO
from rehab_hil.devices.stall import StallMeter
from rehab_hil.devices.tx_line import TxLine
from rehab_hil.protocol import BASE_RATE_HZ, CommandFrame, Configure, FrameDecoder, Message, ResetCause

__all__ = ["SimDevice", "build_parser", "main"]

TICK_S = 1.0 / BASE_RATE_HZ
MAX_CATCH_UP_S = 1.0  # further behind than this, the device is suspended: resync the deadline
MAX_TICKS_PER_WAKE = 20  # catch-up ticks between two looks at the pty and the control channel


class SimDevice(ControlChannel):
    """One simulated device: the firmware core, the plant, a pty master and the fault knobs (its
    outgoing frames and the faults on them: ``tx``, a ``TxLine``).

    ``counts_per_rev`` plays the firmware build's ENCODER_COUNTS_PER_REV (0: adopts CONFIGURE's)."""

    def __init__(self, plant: PlantIO, counts_per_rev: int, clock: str = "realtime", seed: int = 0,
                 estop_normally_closed: bool | None = None) -> None:
        if clock not in ("realtime", "lockstep"):
            raise ValueError(f"clock must be 'realtime' or 'lockstep', got {clock!r}")
        self.plant, self.counts_per_rev, self.clock = plant, counts_per_rev, clock
        self.master, self.slave = os.openpty()
        tty.setraw(self.slave, termios.TCSANOW)
        tty.setraw(self.master, termios.TCSANOW)
        os.set_blocking(self.master, False)
        self.path = os.ttyname(self.slave)
        self.tx = TxLine(self.master, random.Random(seed))  # what the device sends, and the link faults on it
        self.estop_pin = False
        self.estop_wire_broken = False
        self.estop_nc = estop_normally_closed
        self.stalls = StallMeter()  # this process not scheduled: measured, reported, never a fault
        self.commands_seen = 0  # valid COMMAND frames received (evidence the host was alive during a stall)
        self._unwatched = 0  # ticks still to catch up that the watchdog does not count (a stall of this process)
        self.excused_ticks = 0  # all such ticks so far (status: not_scheduled_excused_ms)
        self._woke = 0.0  # when the loop last woke (perf_counter)
        self.running = True
        self._boot(ResetCause.POWER_ON)

    def _boot(self, cause: int) -> None:
        self.core = DeviceCore(self.counts_per_rev, reset_cause=cause, estop_normally_closed=self.estop_nc)
        self.tx.restart()  # seq 0; a reset ends a stall
        self.decoder = FrameDecoder()
        self._send(self.core.boot())

    def _send(self, msgs: Sequence[Message]) -> None:
        self.tx.send(msgs, self.core.ticks)

    # ---- incoming -----------------------------------------------------------------------------

    def on_bytes(self, data: bytes) -> None:
        bad_before = self.decoder.bad_total
        frames = self.decoder.feed(data)
        self.core.count_bad_frame(self.decoder.bad_total - bad_before)
        for frame in frames:
            if isinstance(frame.msg, CommandFrame):
                self.commands_seen += 1
            self._send(self.core.on_frame(frame))
            if isinstance(frame.msg, Configure) and self.core.config is frame.msg:  # accepted: a session starts
                self.plant.start_session()
            if self.clock == "lockstep" and isinstance(frame.msg, CommandFrame) and self.core.streaming:
                for _ in range(self.core.divider):
                    self.tick()

    def tick(self) -> None:
        """One base tick: read the plant at this instant, run the firmware tick, advance the plant."""
        core = self.core
        enc, a0, a1 = self.plant.tick(core.duty, core.direction)
        watch = self._unwatched == 0
        if not watch:
            self._unwatched -= 1
            self.excused_ticks += 1
        self._send(core.tick(Readings(enc, a0, a1, self.estop_pin, self.estop_wire_broken), watch))

    # ---- control channel ----------------------------------------------------------------------

    def _control(self, cmd: str, args: list[str]) -> str | object | None:
        """This device's knobs (see the module docstring); ``estop`` and ``input`` are shared."""
        if cmd in ("drop", "corrupt") and len(args) == 1:
            p = float(args[0])
            if not 0.0 <= p <= 1.0:
                return f"error {cmd} probability must be in 0..1"
            setattr(self.tx, cmd, p)
        elif cmd == "delay" and len(args) == 1:
            self.tx.delay_s = _non_negative(args[0]) / 1000.0
        elif cmd == "garbage" and len(args) == 1:
            self.tx.garbage(int(_non_negative(args[0])))
        elif cmd == "truncate" and not args:
            self.tx.truncate_next = True
        elif cmd == "stall" and len(args) == 1:
            ticks = round(_non_negative(args[0]) * BASE_RATE_HZ / 1000.0)
            self.tx.stall_until_tick = self.core.ticks + ticks if ticks else -1
        elif cmd == "disconnect" and not args:
            self.running = False
        elif cmd == "reboot" and len(args) <= 1:
            causes = {"external": ResetCause.EXTERNAL, "watchdog": ResetCause.HW_WATCHDOG}
            cause = causes.get(args[0] if args else "external")
            if cause is None:
                return f"error reboot cause must be one of {sorted(causes)}"
            self._boot(cause)
        elif cmd == "status" and not args:
            c = self.core
            return (f"ok ticks={c.ticks} samples={c.sample_index} faults={c.faults} rx_bad={c.rx_bad_frames} "
                    f"{self.tx.status()} {self.stalls.status()} "
                    f"not_scheduled_excused_ms={self.excused_ticks * TICK_S * 1e3:.0f}")
        else:
            return UNKNOWN
        return None

    # ---- main loop ----------------------------------------------------------------------------

    def run(self, stdin_fd: int | None = None, out: TextIO = sys.stdout) -> None:
        """Serve until ``disconnect`` or stdin closes."""
        next_tick = time.perf_counter() + TICK_S
        self._woke = next_tick - TICK_S
        pending = b""
        while self.running:
            now = time.perf_counter()
            deadline = next_tick if self.clock == "realtime" else now + 0.05
            deadline = min(deadline, self.tx.next_due())
            fds = [self.master] + ([stdin_fd] if stdin_fd is not None else [])
            readable, _, _ = select.select(fds, [], [], max(0.0, deadline - now))
            woke, commands_before = time.perf_counter(), self.commands_seen
            # the time since the last wake not spent in the sleep asked for: its work, or not scheduled
            lost = (woke - self._woke) - (min(woke, max(now, deadline)) - now)
            self._woke = woke
            if self.master in readable:
                try:
                    data = os.read(self.master, 4096)
                except (BlockingIOError, InterruptedError):
                    data = b""
                except OSError as e:  # EIO: nobody has the slave open any more; wait for one
                    if e.errno != errno.EIO:
                        raise
                    data = b""
                    time.sleep(0.001)
                if data:
                    self.on_bytes(data)
            if stdin_fd is not None and stdin_fd in readable:
                chunk = os.read(stdin_fd, 4096)
                if not chunk:
                    break
                pending += chunk
                while b"\n" in pending:
                    line, pending = pending.split(b"\n", 1)
                    print(self.control(line.decode(errors="replace")), file=out, flush=True)
            if self.clock == "realtime":
                next_tick = self._catch_up(next_tick, lost, self.commands_seen > commands_before)
            self.tx.flush_delayed()
        self.close()

    def _catch_up(self, next_tick: float, lost: float, host_spoke: bool) -> float:
        """Realtime: run the ticks due by now (at most ``MAX_TICKS_PER_WAKE``, then serve the link
        again); first judge whether this process was not scheduled since its last wake (``lost``:
        the time since then not spent in the sleep it asked for; its own work takes well under
        ``STALL_MIN_S``): a stall of the device, whose ticks then do not count towards the watchdog
        if the host spoke meanwhile. Returns the next tick's deadline."""
        if self.stalls.min_s <= lost:
            note = ("the host's commands arrived meanwhile: not counted by the watchdog" if host_spoke
                    else "no command arrived meanwhile: the watchdog counts it")
            if self.stalls.observe(lost, self.core.ticks / BASE_RATE_HZ, note) and host_spoke:
                self._unwatched += int(lost / TICK_S)
        now = time.perf_counter()
        if now - next_tick > MAX_CATCH_UP_S:
            next_tick = now
        self._unwatched = min(self._unwatched, max(0, int((now - next_tick) / TICK_S) + 1))
        for _ in range(MAX_TICKS_PER_WAKE):  # when behind, still serve the link in between
            if now < next_tick:
                break
            self.tick()
            next_tick += TICK_S
        return next_tick

    def close(self) -> None:
        for fd in (self.master, self.slave):
            try:
                os.close(fd)
            except OSError:
                pass


def _non_negative(text: str) -> float:
    v = float(text)
    if not v >= 0.0 or v == float("inf"):
        raise ValueError(f"expected a finite number >= 0, got {text!r}")
    return v


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="python -m sim_devices.python_device",
                                description="Python simulated rig device on a pty (protocol v1).")
    p.add_argument("--config", required=True, help="plant config (configs/*.toml)")
    p.add_argument("--clock", choices=("realtime", "lockstep"), default="realtime")
    p.add_argument("--adc-noise-counts", type=float, default=0.0, help="ADC noise standard deviation [counts]")
    p.add_argument("--seed", type=int, default=0, help="seed of the noise and fault injection")
    p.add_argument("--drop", type=float, default=0.0, help="probability of dropping an outgoing frame")
    p.add_argument("--corrupt", type=float, default=0.0, help="probability of corrupting an outgoing frame")
    p.add_argument("--delay-ms", type=float, default=0.0, help="delay of every outgoing frame [ms]")
    p.add_argument("--sim-patient", default=None, help="a simulated patient on the plant (profiles/sim/*.toml)")
    p.add_argument("--sim-truth", default=None,
                   help="write the rig's true state here (sim_truth.csv: the actuator's temperature, the patient's)")
    p.add_argument("--fifo-priority", type=int, default=5,
                   help="SCHED_FIFO priority in realtime mode (0: none; below the host loop's 10); an MCU is never "
                        "descheduled (a stall that still happens is measured and reported, never a fault; "
                        "docs/loop.md, 'Scheduling')")
    return p


def _plant(args: argparse.Namespace, truth: str | None) -> tuple[Any, Any]:
    """The config and the device's plant (with its patient), its kernels compiled or loaded: one step."""
    from rehab_hil.devices.patient_plant import patient_plant
    from rehab_hil.loading import load_config
    from rehab_hil.plants import get_plant

    cfg = load_config(args.config)
    spec = get_plant(cfg.plant)
    if spec.device is None:
        raise ValueError(f"plant {cfg.plant!r} has no device binding")
    plant = patient_plant(cfg, spec.device(cfg), args.sim_patient, truth, adc_noise_counts=args.adc_noise_counts,
                          seed=args.seed)
    plant.tick([0, 0], 0)  # compile the kernels before announcing the port
    return cfg, plant


def warm(argv: Sequence[str]) -> None:
    """In the zygote (``rehab_hil.launch``), before it forks this device: load the plant's kernels, so that
    the device and every later one with the same plant start with them in memory (no truth file written)."""
    _plant(build_parser().parse_args(argv), None)


def main(argv: Sequence[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    from rehab_hil.config import ConfigError

    try:
        cfg, plant = _plant(args, args.sim_truth)
        plant.reset()  # the initial state, the session clock at 0
        estop = cfg.rig.estop
        device = SimDevice(plant, 0, clock=args.clock, seed=args.seed,  # 0: adopts CONFIGURE's, as the firmware
                           estop_normally_closed=estop.normally_closed if estop is not None else False)
        for knob in ("drop", "corrupt"):
            device.control(f"{knob} {getattr(args, knob)}")
        reply = device.control(f"delay {args.delay_ms}")
        if reply.startswith("error") or not 0 <= args.drop <= 1 or not 0 <= args.corrupt <= 1:
            raise ValueError("fault knobs: probabilities in 0..1, delay >= 0")
    except (ConfigError, ValueError, KeyError) as e:
        print(f"sim device: error: {e}", file=sys.stderr)
        return 2
    if args.clock == "realtime" and args.fifo_priority > 0:
        from rehab_hil.loop.timing import lock_memory, realtime_setup

        report = realtime_setup(args.fifo_priority)  # a real MCU is never descheduled, nor paged out
        print(f"sim device: scheduler {report.scheduler}, memory {lock_memory()}", file=sys.stderr, flush=True)
    print(device.path, flush=True)
    try:
        device.run(stdin_fd=sys.stdin.fileno())
    except KeyboardInterrupt:
        device.close()
    finally:
        if plant.truth_sink is not None:
            plant.truth_sink.close()  # type: ignore[attr-defined]
    return 0
