"""One way to open a rig: ``open_rig(device, config)`` for every backend, connected and ready to
configure.

``device``: "sim" (the Python simulated device on a pty), "avr" (the firmware in simavr), "inprocess"
(``InProcessHardware``: the device logic and the plant in this process, lockstep), or a serial path
(a real board), or "auto" (the one Arduino-like USB serial port). The config's plant closes the
loop of the simulated backends.
"""

from __future__ import annotations

from collections.abc import Iterator, Mapping, Sequence
from contextlib import ExitStack, contextmanager
from pathlib import Path
from typing import Any

from rehab_hil.hardware.discovery import announce_device, resolve_device
from rehab_hil.hardware.inprocess import InProcessHardware
from rehab_hil.hardware.interface import HardwareError, HardwareInterface

__all__ = ["RIG_KINDS", "inprocess_hardware", "open_rig"]

RIG_KINDS = ("sim", "avr", "inprocess")  # anything else is a serial path


def inprocess_hardware(binding: Any, *, adc_noise_counts: float = 0.0, seed: int = 0,
                       hello: Mapping[str, int] | None = None, bursts: Sequence[int] = (1,)) -> InProcessHardware:
    """``InProcessHardware`` on a plant's rig binding (``DeviceBinding``), not yet connected; ``bursts``:
    sample periods per COMMAND, cycled (a USB bridge's bursts, deterministically)."""
    from rehab_hil.devices.plant_io import PlantIO  # the model framework: imported only when needed

    plant = PlantIO(binding, adc_noise_counts=adc_noise_counts, seed=seed)
    return InProcessHardware(plant, binding.encoder_counts_per_rev, hello=hello, bursts=bursts)


@contextmanager
def open_rig(device: str, config_path: str | Path, *, lockstep: bool = False, baud: int | None = None,
             connect_timeout_s: float = 3.0, write_timeout_s: float = 0.2,
             spawn_args: list[str] | None = None, sim_patient: str | Path | None = None,
             sim_truth: str | Path | None = None, cfg: Any = None,
             loaded_patient: Any = None) -> Iterator[HardwareInterface]:
    """Open ``device`` (see the module docstring) on the plant of ``config_path`` and connect (HELLO);
    closes the hardware and stops a spawned device process on exit. ``lockstep``: the simulated
    device runs in virtual time, one sample period per COMMAND (deterministic; "inprocess" always
    does; "avr": the harness stops simulated time once the firmware has answered the host).
    ``baud``: a serial path's rate (default ``[rig].baud``). ``sim_patient``: a simulated patient
    (``profiles/sim/*.toml``) on a simulated device's plant; ``sim_truth``: where a simulated device
    writes its true state (``sim_truth.csv``: the actuator's temperature, and the patient's, if any).
    ``cfg``, ``loaded_patient``: ``config_path`` and ``sim_patient`` already loaded (a session loads each
    once; the in-process device takes them as they are). Failures raise ``HardwareError``."""
    cfg = cfg if cfg is not None else _config(config_path)
    device = resolve_device(device)  # "auto": the one Arduino-like USB serial port (hardware/discovery.py)
    announce_device(device, config_path, cfg.rig.port)  # which device, on stderr
    with ExitStack() as stack:
        hw: HardwareInterface
        patient = ["--sim-patient", str(sim_patient)] if sim_patient is not None else []
        if sim_truth is not None:
            patient += ["--sim-truth", str(sim_truth)]
        if device == "inprocess":
            hw = _inprocess(stack, cfg, loaded_patient if loaded_patient is not None else sim_patient, sim_truth)
        else:
            from rehab_hil.hardware.serial_hw import SerialHardware

            port, proc = device, None
            if device in ("sim", "avr"):
                proc = stack.enter_context(_spawn(device, config_path, lockstep, [*(spawn_args or []), *patient]))
                port = proc.port
            elif lockstep:
                raise HardwareError(f"lockstep is a mode of the simulated devices, not of {device}")
            never = {"resend_s": None} if lockstep else {}  # virtual time: a resend would cost device time
            hw = SerialHardware(port, baud or cfg.rig.baud, write_timeout_s=write_timeout_s, **never)
            hw.device_process = proc
        stack.callback(hw.close)
        hw.connect(timeout=connect_timeout_s)
        yield hw


def _inprocess(stack: ExitStack, cfg: Any, sim_patient: Any,
               sim_truth: str | Path | None) -> InProcessHardware:
    """The in-process rig, with a simulated patient on its plant when one is given, writing its truth
    when asked to."""
    from rehab_hil.plants import get_plant

    binding = get_plant(cfg.plant).device(cfg)
    if sim_patient is None and sim_truth is None:
        return inprocess_hardware(binding)
    from rehab_hil.config import ConfigError
    from rehab_hil.devices.patient_plant import patient_plant

    try:
        plant = patient_plant(cfg, binding, sim_patient, sim_truth)
    except (ConfigError, ValueError) as e:
        raise HardwareError(f"inprocess device: {e}") from None
    if plant.truth_sink is not None:
        stack.callback(plant.truth_sink.close)  # type: ignore[attr-defined]
    return InProcessHardware(plant, binding.encoder_counts_per_rev)


def _spawn(kind: str, config_path: str | Path, lockstep: bool, extra_args: list[str] | None) -> Any:
    from rehab_hil.devices import spawn_device
    from rehab_hil.devices.spawn import DeviceProcessError

    if kind == "avr":
        from rehab_hil.devices import avr_device

        reason = avr_device.unavailable_reason()
        if reason:
            raise HardwareError(f"avr device: {reason}")
    try:
        return spawn_device(kind, config_path, clock="lockstep" if lockstep else "realtime", extra_args=extra_args)
    except DeviceProcessError as e:
        raise HardwareError(f"{kind} device: {e}") from e


def _config(config_path: str | Path) -> Any:
    from rehab_hil.loading import load_config

    return load_config(config_path)
