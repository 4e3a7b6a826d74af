"""Start the Python simulated device as a child process and hand out its pty path.

``spawn_sim_device(config, clock=...)`` returns a ``SimDeviceProcess`` (``.port``, ``.control()``,
``.set_estop_input()``, ``.close()``; a context manager). The avr spawner
(``rehab_hil.devices.avr_device``) has the same shape.
"""

from __future__ import annotations

import os
import select
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from types import TracebackType
from typing import Any

from rehab_hil import launch
from rehab_hil.devices.stall import parse_status
from rehab_hil.devices.starvation import Starvation

__all__ = ["DeviceProcessError", "DeviceProcessView", "SimDeviceProcess", "maybe_bridged", "spawn_sim_device",
           "usb_bridge_wanted"]


class DeviceProcessError(RuntimeError):
    """The device process failed to start, died, or refused a control command."""


class DeviceProcessView:
    """A local simulated device's process seen from a loop process (``loop.process``): alive, starved;
    its own stall counts are asked for by the session's process, which holds its control channel."""

    def __init__(self, pid: int) -> None:
        self.pid = pid

    def alive(self) -> bool:
        return Starvation(self.pid).alive()

    def starvation(self) -> Starvation:
        return Starvation(self.pid)

    def reported_stalls(self) -> dict[str, float]:
        return {}


class SimDeviceProcess:
    """A running Python simulated device; terminate it with ``close()`` (also on errors)."""

    kind = "python"

    def __init__(self, argv: list[str], ready_timeout_s: float = 120.0,
                 warm: tuple[str, tuple[Any, ...]] | None = None) -> None:
        self._stderr = tempfile.TemporaryFile()
        # its own process group: Ctrl-C in the terminal reaches the host alone, which then stops the device
        # as it stops a real one (PWM 0, confirmed), not a device killed under it (a link loss)
        self.proc = launch.popen(argv, stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=self._stderr, bufsize=0,
                                 process_group=0, warm=warm)  # forked from the warm zygote (rehab_hil.launch)
        self._buf = b""
        try:
            self.port = self._readline(ready_timeout_s)
        except DeviceProcessError:
            self.close()
            raise
        if not self.port.startswith("/dev/"):
            self.close()
            raise DeviceProcessError(f"device printed {self.port!r} instead of its pty path")

    @property
    def pid(self) -> int:
        return self.proc.pid

    def alive(self) -> bool:
        return self.proc.poll() is None

    def stderr_text(self) -> str:
        self._stderr.seek(0)
        return self._stderr.read().decode(errors="replace")

    def _readline(self, timeout: float) -> str:
        assert self.proc.stdout is not None
        fd = self.proc.stdout.fileno()
        deadline = time.monotonic() + timeout
        while b"\n" not in self._buf:
            remaining = deadline - time.monotonic()
            if remaining <= 0:
                raise DeviceProcessError(f"no answer from the device process within {timeout:.1f} s")
            ready, _, _ = select.select([fd], [], [], remaining)
            if ready:
                chunk = os.read(fd, 4096)
                if not chunk:
                    self.proc.wait(timeout=5)
                    raise DeviceProcessError(f"device process exited ({self.proc.returncode}): "
                                             f"{self.stderr_text().strip()[-2000:]}")
                self._buf += chunk
        line, self._buf = self._buf.split(b"\n", 1)
        return line.decode(errors="replace").strip()

    def control(self, command: str, timeout: float = 5.0) -> str:
        """Send one control-channel line (see ``rehab_hil.devices.sim_device``); returns the ok reply."""
        if not self.alive() or self.proc.stdin is None:
            raise DeviceProcessError("device process is not running")
        self.proc.stdin.write(command.encode() + b"\n")
        reply = self._readline(timeout)
        if not reply.startswith("ok"):
            raise DeviceProcessError(f"control {command!r}: {reply}")
        return reply

    def starvation(self) -> Starvation:
        """How long this device's processes could not run (the host's view of its stalls)."""
        return Starvation(self.pid)

    def reported_stalls(self) -> dict[str, float]:
        """The stalls the device measured of its own process (``status``: ``not_scheduled*``);
        {} when it cannot answer (exited, or a bridge that does not pass ``status`` on)."""
        try:
            return parse_status(self.control("status", timeout=2.0))
        except (DeviceProcessError, OSError):
            return {}

    def view(self) -> DeviceProcessView:
        """What a loop process needs of this device's process: whether it runs, and its starvation."""
        return DeviceProcessView(self.pid)

    def set_estop_input(self, active: bool) -> None:
        """Drive the e-stop input pin (active = pressed)."""
        self.control(f"estop {1 if active else 0}")

    def close(self) -> None:
        """Stop the process (stdin closed, then terminate, then kill); idempotent."""
        p = self.proc
        if p.poll() is None:
            try:
                if p.stdin is not None:
                    p.stdin.close()
                p.wait(timeout=2)
            except (subprocess.TimeoutExpired, OSError):
                p.terminate()
                try:
                    p.wait(timeout=2)
                except subprocess.TimeoutExpired:
                    p.kill()
                    p.wait()
        for f in (p.stdin, p.stdout):
            if f is not None:
                try:
                    f.close()
                except OSError:
                    pass
        self._stderr.close()

    def __enter__(self) -> SimDeviceProcess:
        return self

    def __exit__(self, exc_type: type[BaseException] | None, exc: BaseException | None,
                 tb: TracebackType | None) -> None:
        self.close()


def usb_bridge_wanted(config_path: str | Path, usb_bridge: bool | None) -> bool:
    """``usb_bridge`` if given, else the config's ``[rig.link] usb_bridge`` (absent: off)."""
    if usb_bridge is not None:
        return usb_bridge
    from rehab_hil.config import ConfigError, load_toml

    try:
        rig = load_toml(config_path).get("rig", {})
    except ConfigError:  # the device process reports a bad config itself, naming file and key
        return False
    link = rig.get("link", {}) if isinstance(rig, dict) else {}
    return bool(link.get("usb_bridge", False)) if isinstance(link, dict) else False


def maybe_bridged(config_path: str | Path, argv: list[str], usb_bridge: bool | None, seed: int = 0,
                  native_bootloader: bool = False) -> list[str]:
    """``argv`` behind the Uno's USB bridge model (``devices/usb_bridge.py``) when wanted."""
    if not usb_bridge_wanted(config_path, usb_bridge):
        return argv
    from rehab_hil.devices.usb_bridge import bridged_argv

    return bridged_argv(str(config_path), argv, seed, native_bootloader)


def spawn_sim_device(config_path: str | Path, clock: str = "realtime", *, extra_args: list[str] | None = None,
                     ready_timeout_s: float = 120.0, usb_bridge: bool | None = None) -> SimDeviceProcess:
    """Start ``rehab_hil.devices.sim_device`` on ``config_path``; returns once its pty is ready.
    ``usb_bridge`` (default: the config's ``[rig.link]``) puts the Uno's USB-bridge model between."""
    args = ["--config", str(config_path), "--clock", clock, *(extra_args or [])]
    argv = [sys.executable, "-c", "import sys; from rehab_hil.devices.sim_device import main; sys.exit(main())", *args]
    bridged = maybe_bridged(config_path, argv, usb_bridge)
    warm = ("rehab_hil.devices.sim_device:warm", (args,)) if bridged is argv else None  # its plant's kernels
    return SimDeviceProcess(bridged, ready_timeout_s, warm)
