"""The real firmware in simavr, closed with the same plant model as the Python device.

Process layout: ``spawn_avr_device(config)`` starts this module as a driver process; the driver
starts ``sim_devices/build/avr_harness`` (C, libsimavr) on ``firmware/build/rehab_fw.elf`` in
lockstep mode (``-l 1000``): every 1 ms of simulated time the harness stops and prints the PWM
state it read from the AVR's registers (``T sim_us duty0 duty1 dir ...``); the driver steps the
plant (``PlantIO``, shared with the Python device) one base tick with those duties and answers
``G encoder_count adc0_mV adc1_mV estop_level``; the harness then drives the quadrature edges,
the ADC inputs and the e-stop pin and runs the next millisecond. The harness throttles simulated
time to the wall clock (``--clock realtime``; ``--clock free`` runs as fast as it can), so the
firmware's millisecond timeouts and the host's agree. The pty the host opens belongs to the
harness; the driver prints its path as its first stdout line.

Control channel (stdin, one command per line, each answered by ``ok ...`` or ``error ...``), the
subset of the Python device's that a real firmware allows: ``estop 0|1``, ``estop_wire ok|broken``,
``input NAME VALUE``,
``reboot [external]`` (an external reset of the AVR), ``status`` (with the device's own stalls,
``not_scheduled=N ..._total_ms ..._max_ms``). Stdin closing ends the driver and with it the harness.

Stalls (``devices/stall.py``): when the harness or this driver is not scheduled, simulated time
stops with it (the harness never runs more than 20 ms behind the wall clock), so the firmware's
own watchdog cannot see the stall; the driver measures it (simulated time falling behind the wall
clock at once by ``STALL_MIN_S`` or more between two T lines), logs it on stderr and counts it.
"""

from __future__ import annotations

import argparse
import os
import select
import subprocess
import sys
import time
from collections.abc import Sequence
from pathlib import Path

from rehab_hil.devices.control import UNKNOWN, ControlChannel
from rehab_hil.devices.core import Readings
from rehab_hil.devices.plant_io import ADC_MAX, PlantIO
from rehab_hil.devices.spawn import DeviceProcessError, SimDeviceProcess, maybe_bridged, usb_bridge_wanted
from rehab_hil.devices.stall import StallMeter

__all__ = ["AvrDeviceProcess", "adc_counts_to_mv", "default_paths", "main", "spawn_avr_device", "unavailable_reason"]

ROOT = Path(__file__).resolve().parents[3]
ADC_REF_MV = 5000
CLOCKS = ("realtime", "free", "lockstep")


def default_paths() -> tuple[Path, Path]:
    """(harness binary, firmware ELF) as built by ``make harness firmware``."""
    return ROOT / "sim_devices" / "build" / "avr_harness", ROOT / "firmware" / "build" / "rehab_fw.elf"


def optiboot_path() -> Path:
    """The Uno's bootloader as ``make firmware`` builds it (firmware/Makefile: Debian's optiboot source)."""
    return ROOT / "firmware" / "build" / "optiboot" / "optiboot_atmega328.hex"


def unavailable_reason() -> str | None:
    """Why the avr device cannot start here (a binary not built), or None."""
    for p in default_paths():
        if not p.exists():
            return f"{p} is missing: run `make firmware harness`"
    return None


def adc_counts_to_mv(counts: int) -> int:
    """The input voltage [mV] that simavr's ADC (``mV * 1023 / 5000``, truncated) reads as ``counts``:
    the middle of the count's voltage band, so truncation cannot land on the neighbour."""
    c = min(max(int(counts), 0), ADC_MAX)
    if c == ADC_MAX:
        return ADC_REF_MV
    return round((c + 0.5) * ADC_REF_MV / ADC_MAX)


class AvrDeviceProcess(SimDeviceProcess):
    """A running firmware-in-simavr device: ``.port``, ``.control()``, ``.set_estop_input()``, ``.close()``."""

    kind = "avr"


def spawn_avr_device(config_path: str | Path, clock: str = "realtime", *, extra_args: list[str] | None = None,
                     ready_timeout_s: float = 120.0, usb_bridge: bool | None = None) -> AvrDeviceProcess:
    """Start the firmware in simavr behind the plant of ``config_path``; returns once its pty is ready.

    ``clock``: "realtime" (simulated time throttled to the wall clock), "free" (as fast as the
    simulator runs) or "lockstep" (virtual time paced by the host's frames; see the module docstring).
    ``usb_bridge`` (default: the config's ``[rig.link]``) puts the Uno's USB-bridge model between.
    Build first: ``make firmware harness``."""
    if clock not in CLOCKS:
        raise ValueError(f"the avr device supports clock {CLOCKS}, not {clock!r}")
    harness, elf = default_paths()
    for p in (harness, elf):
        if not p.exists():
            raise DeviceProcessError(f"{p} is missing: run `make firmware harness`")
    bridged = usb_bridge_wanted(config_path, usb_bridge)
    uno = ["--uno"] if bridged and optiboot_path().exists() else []  # behind the bridge: the whole Uno
    argv = [sys.executable, "-c", "import sys; from rehab_hil.devices.avr_device import main; sys.exit(main())",
            "--config", str(config_path), "--clock", clock, *uno, *(extra_args or [])]
    return AvrDeviceProcess(maybe_bridged(config_path, argv, bridged, native_bootloader=bool(uno)), ready_timeout_s)


class _Driver(ControlChannel):
    """Closes the loop between the harness (lockstep lines on a pipe) and the plant."""

    def __init__(self, plant: PlantIO, harness_argv: list[str], estop_normally_closed: bool = False) -> None:
        self.plant = plant
        self.estop_pin = False
        self.estop_wire_broken = False
        self.estop_nc = estop_normally_closed
        self.ticks = 0
        self.last_t = ""
        self.realtime = True  # simulated time throttled to the wall clock: stalls are measured
        self.stalls = StallMeter(name="avr device")  # the harness or this driver not scheduled
        self._origin: tuple[float, int] | None = None  # (wall clock, simulated us) of the first T line
        self._behind_s = 0.0  # how far simulated time was behind the wall clock at the last T line
        self.proc = subprocess.Popen(harness_argv, stdin=subprocess.PIPE, stdout=subprocess.PIPE, bufsize=0)
        self._out = b""
        self.port = self._harness_line(timeout=10.0)
        if not self.port.startswith("/dev/"):
            raise DeviceProcessError(f"harness printed {self.port!r} instead of its pty path")

    def _harness_line(self, timeout: float | None = None) -> str:
        assert self.proc.stdout is not None
        fd = self.proc.stdout.fileno()
        while b"\n" not in self._out:
            ready, _, _ = select.select([fd], [], [], timeout)
            if not ready:
                raise DeviceProcessError("the harness did not answer")
            chunk = os.read(fd, 65536)
            if not chunk:
                raise DeviceProcessError(f"the harness exited ({self.proc.wait()})")
            self._out += chunk
        line, self._out = self._out.split(b"\n", 1)
        return line.decode(errors="replace").strip()

    def _send(self, line: str) -> None:
        assert self.proc.stdin is not None
        self.proc.stdin.write(line.encode() + b"\n")

    def on_state(self, line: str) -> None:
        """One lockstep boundary: read the PWM state, step the plant one tick, drive the inputs."""
        f = line.split()
        duty0, duty1, direction = int(f[2]), int(f[3]), int(f[4])
        if self.realtime:
            self._measure_stall(int(f[1]))
        enc, a0, a1 = self.plant.tick((duty0, duty1), direction)
        self.ticks += 1
        self.last_t = line
        estop_level = int(Readings(estop_pin=self.estop_pin, estop_wire_broken=self.estop_wire_broken)
                          .pin_high(self.estop_nc))  # D4 as the rig's loop is wired
        self._send(f"G {enc} {adc_counts_to_mv(a0)} {adc_counts_to_mv(a1)} {estop_level}")

    def _measure_stall(self, sim_us: int) -> None:
        """Simulated time against the wall clock: a jump behind is a stall of this device's processes."""
        now = time.perf_counter()
        if self._origin is None:
            self._origin = (now, sim_us)
            return
        behind = (now - self._origin[0]) - (sim_us - self._origin[1]) * 1e-6
        self.stalls.observe(behind - self._behind_s, sim_us * 1e-6,
                            "simulated time stopped with it: the firmware's watchdog cannot see it")
        self._behind_s = behind

    def _control(self, cmd: str, args: list[str]) -> str | object | None:
        """This device's knobs; ``estop`` and ``input`` are shared (devices/control.py)."""
        if cmd == "reboot" and args in ([], ["external"]):
            self._send("R")
        elif cmd == "status" and not args:
            f = self.last_t.split()
            fields = ("sim_us", "duty0", "duty1", "dir", "encoder", "resets", "tx_dropped", "rx_dropped",
                      "rx_frames_hit")
            kv = " ".join(f"{k}={v}" for k, v in zip(fields, f[1:], strict=False))
            return f"ok ticks={self.ticks} {kv} {self.stalls.status()}"
        else:
            return UNKNOWN
        return None

    def run(self, stdin_fd: int) -> None:
        assert self.proc.stdout is not None
        hfd = self.proc.stdout.fileno()
        pending = b""
        while True:
            while b"\n" in self._out:
                line, self._out = self._out.split(b"\n", 1)
                text = line.decode(errors="replace")
                if text.startswith("T "):
                    self.on_state(text)
                elif text.startswith("X "):
                    print(f"avr device: the AVR stopped ({text})", file=sys.stderr)
                    return
            ready, _, _ = select.select([hfd, stdin_fd], [], [])
            if hfd in ready:
                chunk = os.read(hfd, 65536)
                if not chunk:
                    return
                self._out += chunk
            if stdin_fd in ready:
                chunk = os.read(stdin_fd, 4096)
                if not chunk:
                    return
                pending += chunk
                while b"\n" in pending:
                    line, pending = pending.split(b"\n", 1)
                    print(self.control(line.decode(errors="replace")), flush=True)

    def close(self) -> None:
        p = self.proc
        if p.poll() is None:
            try:
                if p.stdin is not None:
                    p.stdin.close()  # EOF on its stdin ends the harness
                p.wait(timeout=2)
            except (subprocess.TimeoutExpired, OSError):
                p.kill()
                p.wait()
        if p.stdout is not None:
            p.stdout.close()


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="python -m rehab_hil.devices.avr_device",
                                description="The firmware in simavr on a pty, closed with a plant model.")
    p.add_argument("--config", required=True, help="plant config (configs/*.toml)")
    p.add_argument("--clock", choices=CLOCKS, default="realtime")
    p.add_argument("--harness", type=Path, default=None, help="avr_harness binary")
    p.add_argument("--elf", type=Path, default=None, help="firmware ELF")
    p.add_argument("--adc-noise-counts", type=float, default=0.0, help="ADC noise standard deviation [counts]")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--edge-us", type=int, default=50, help="simulated time between two encoder edges [us]")
    p.add_argument("--fifo-priority", type=int, default=5,
                   help="SCHED_FIFO priority of this driver and the harness (it inherits it) with --clock realtime "
                        "(0: none); below the host loop's 10, as the Python device (docs/loop.md, 'Scheduling')")
    p.add_argument("--sim-patient", default=None, help="a simulated patient on the plant (profiles/sim/*.toml)")
    p.add_argument("--sim-truth", default=None,
                   help="write the rig's true state here (sim_truth.csv: the actuator's temperature, the patient's)")
    p.add_argument("--uno", action="store_true", help="the whole Uno: optiboot loaded with the sketch (harness -b) "
                   "and the UART's real receive rate into its 2-byte buffer (-u)")
    return p


def main(argv: Sequence[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    from rehab_hil.config import ConfigError
    from rehab_hil.devices.patient_plant import patient_plant
    from rehab_hil.loading import load_config
    from rehab_hil.plants import get_plant

    harness, elf = default_paths()
    harness, elf = args.harness or harness, args.elf or elf
    try:
        cfg = load_config(args.config)
        spec = get_plant(cfg.plant)
        if spec.device is None:
            raise ValueError(f"plant {cfg.plant!r} has no device binding")
        binding = spec.device(cfg)
        plant = patient_plant(cfg, binding, args.sim_patient, args.sim_truth, adc_noise_counts=args.adc_noise_counts,
                              seed=args.seed)
        plant.tick([0, 0], 0)  # compile the kernels before the firmware starts
        plant.reset()  # the initial state, the session clock at 0
    except (ConfigError, ValueError, KeyError) as e:
        print(f"avr device: error: {e}", file=sys.stderr)
        return 2
    argv_h = [str(harness), "-l", "1000", "-e", str(args.edge_us)]
    if args.clock == "free":
        argv_h.append("-f")
    elif args.clock == "lockstep":
        argv_h.append("-k")
    if args.uno:
        argv_h += ["-b", str(optiboot_path()), "-u"]
    if args.clock == "realtime" and args.fifo_priority > 0:  # before the harness starts: it inherits the policy
        from rehab_hil.loop.timing import lock_memory, realtime_setup

        report = realtime_setup(args.fifo_priority)  # a real MCU is never descheduled, nor paged out
        print(f"avr device: scheduler {report.scheduler}, memory {lock_memory()}", file=sys.stderr, flush=True)
    estop = cfg.rig.estop
    driver = _Driver(plant, [*argv_h, str(elf)], estop.normally_closed if estop is not None else False)
    driver.realtime = args.clock == "realtime"
    print(driver.port, flush=True)
    try:
        driver.run(sys.stdin.fileno())
    except KeyboardInterrupt:
        pass
    finally:
        driver.close()
        if plant.truth_sink is not None:
            plant.truth_sink.close()  # type: ignore[attr-defined]
    return 0


if __name__ == "__main__":
    sys.exit(main())
