"""What tests and benchmarks share: a free loopback port, an in-process rig, and sim-plant configs
with changes that start mid-session (``config_with_changes``).

The in-process rig is ``InProcessHardware`` (the firmware's logic and the config's plant in this
process, one SAMPLE per COMMAND): deterministic and without a pty or a subprocess, so the loop
service, the recorder and the telemetry publisher can run inside a unit test or a benchmark.
"""

from __future__ import annotations

import json
import socket
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

from rehab_hil import shipped
from rehab_hil.hardware.inprocess import InProcessHardware
from rehab_hil.hardware.open import inprocess_hardware

__all__ = [
    "CONFIGS",
    "InProcessHardware",
    "config_with_changes",
    "config_with_lines",
    "free_port",
    "inprocess_rig",
    "pid_runtime",
    "push_runtime",
    "servo_axis_config",
]

CONFIGS = shipped.CONFIGS  # the plant configs: the repository's, or an installed wheel's own copies


def servo_axis_config(path: Path, load: str = "", drive: str = 'command = "torque"\nsaturation_nm = 0.3',
                      extra: str = "") -> Path:
    """Write a small rotary servo axis commanded open loop (``motor_axis``: 2e-4 kg m^2, 4e-4 N m s/rad,
    1 kHz) to ``path``: ``load`` adds keys to its ``[load]`` table, ``drive`` is its ``[drive]`` table,
    ``extra`` follows (an ``[import]`` mapping); the rig table is EMPS's (a lab's records bind no rig)."""
    emps = (CONFIGS / "emps.toml").read_text()
    path.write_text('plant = "motor_axis"\n[simulation]\nstep_s = 0.001\nsubsteps = 1\n[load]\nkind = "rotary"\n'
                    f"inertia_kg_m2 = 2.0e-4\nviscous_nm_s_per_rad = 4.0e-4\n{load}\n[drive]\n{drive}\n{extra}\n"
                    + emps[emps.index("[rig]"):])
    return path


def free_port() -> int:
    """A TCP port on 127.0.0.1 that was free a moment ago (another process may still take it)."""
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def inprocess_rig(config_path: str | Path = CONFIGS / "finger_extensor.toml", *, configured: bool = True,
                  hello: Mapping[str, int] | None = None, bursts: tuple[int, ...] = (1,)) -> InProcessHardware:
    """An in-process rig on the plant of ``config_path``, connected and, when ``configured``, given
    the config's CONFIGURE (ACTIVE: each ``write_command`` returns the next sample at once).
    ``hello`` overrides fields of the device's HELLO (a different firmware version, fewer channels);
    ``bursts`` are the sample periods each command runs, cycled (a USB bridge's 2-3 at a time)."""
    from rehab_hil.loading import load_config
    from rehab_hil.plants import get_plant
    from rehab_hil.service import assembly

    cfg = load_config(config_path)
    binding = get_plant(cfg.plant).device(cfg)
    hw = inprocess_hardware(binding, hello=hello, bursts=bursts)
    hw.connect()
    if configured:
        hw.configure(assembly.firmware_configure(cfg, binding))
    return hw


def pid_runtime(cfg, target_deg: float | None = None, *, sine: tuple[float, float, float] | None = None,
                gains: tuple[float, float, float, float] | None = None) -> Any:
    """A PID on the encoder angle for the loop (``ControllerRuntime``), as the rig's ``pid``
    controller builds it, toward a constant ``target_deg`` or along ``sine`` = (offset [deg],
    amplitude [deg], frequency [Hz]); ``gains`` (kp, ki, kd, derivative filter) override
    ``[controllers.pid]``. No pre-flight run: tests drive it where they want."""
    from rehab_hil.control.trajectories import SineReference
    from rehab_hil.controllers import ControlContext, Controller, Reference
    from rehab_hil.controllers.pid import PID, PIDSettings, feedback_parts, limit_part
    from rehab_hil.loop.controllers import ControllerRuntime

    ctx = ControlContext.of(cfg)
    settings = cfg.controllers.get("pid")
    if gains is not None:
        settings = PIDSettings(kp_per_deg=gains[0], ki_per_deg_s=gains[1], kd_s_per_deg=gains[2],
                               derivative_filter_s=gains[3])
    ref = Reference.step(cfg, target_deg if target_deg is not None else cfg.rig.session.step_deg)
    if sine is None:
        return ControllerRuntime(PID.build(ctx, settings, ref))
    demand = f"{ctx.effort}_demand"
    parts = [SineReference("reference", rename={"reference": ctx.reference}, offset=sine[0], amplitude=sine[1],
                           frequency_hz=sine[2]),
             *feedback_parts(ctx, settings, demand, ctx.effort_bounds), *limit_part(ctx, demand)]
    return ControllerRuntime(Controller("pid", ctx, ref, parts, sums=(demand,)))


def push_runtime(cfg, duty: float, on_s: float = 600.0, off_s: float = 0.0) -> Any:
    """A steady open-loop push at ``duty`` (the ``pulsed`` controller, one long pulse)."""
    from rehab_hil.controllers import ControlContext, Reference
    from rehab_hil.controllers.pulsed import Pulsed, PulsedSettings
    from rehab_hil.loop.controllers import ControllerRuntime

    ctx = ControlContext.of(cfg)
    scale = ctx.ports.actuators[0].duty_scale
    settings = PulsedSettings(effort=duty * scale, on_s=on_s, off_s=off_s)
    return ControllerRuntime(Pulsed.build(ctx, settings, Reference.session(cfg)))


def _toml_value(v: Any) -> str:
    """A scalar or a flat table as TOML (strings, numbers, booleans, inline tables of those)."""
    if isinstance(v, Mapping):
        return "{ " + ", ".join(f"{k} = {_toml_value(x)}" for k, x in v.items()) + " }"
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, int | float):
        return repr(float(v)) if isinstance(v, float) else str(v)
    if isinstance(v, str):
        return json.dumps(v)  # a TOML basic string
    raise TypeError(f"cannot write {type(v).__name__} {v!r} as a TOML value here")


def config_with_changes(base_path: str | Path, out_path: str | Path, *,
                        effects: Sequence[Mapping[str, Any]] = (),
                        changes: Sequence[Mapping[str, Any]] = ()) -> Path:
    """Write ``out_path``: the plant config ``base_path`` plus ``[[effects]]`` and ``[[changes]]`` tables
    (each a mapping of its keys, e.g. ``{"name": "coulomb_friction", "params": {"level_nm": 0.05},
    "start_s": 1.0}``, ``{"key": "motor.supply_v", "scale": 0.92, "start_s": 30.0, "ramp_s": 5.0}``)
    for ``rehab-hil run --sim-plant`` (it takes a file). The result is loaded once, so a bad entry
    raises the ConfigError a user would see. A relative ``force_calibration`` of the base is taken
    as it stands, relative to ``out_path``'s folder."""
    from rehab_hil.loading import load_config

    text = Path(base_path).read_text()
    for table, entries in (("effects", effects), ("changes", changes)):
        for entry in entries:
            text += f"\n[[{table}]]\n" + "".join(f"{k} = {_toml_value(v)}\n" for k, v in entry.items())
    out = Path(out_path)
    out.write_text(text)
    load_config(out)
    return out


def config_with_lines(base_path: str | Path, out_path: str | Path, replacements: Mapping[str, str]) -> Path:
    """Write ``out_path``: the config ``base_path`` with each text ``old`` of ``replacements`` replaced
    (once) by its ``new`` (a test's rig that differs from the shipped one by a line); an ``old`` the file
    does not hold raises ValueError (the shipped file changed under the test)."""
    text = Path(base_path).read_text()
    for old, new in replacements.items():
        if old not in text:
            raise ValueError(f"{base_path}: no {old!r} to replace")
        text = text.replace(old, new, 1)
    out = Path(out_path)
    out.write_text(text)
    return out
