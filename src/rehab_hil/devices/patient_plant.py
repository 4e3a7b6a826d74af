"""The simulated device's plant with a patient on it: the one place ``--sim-patient`` turns into a
plant behind the rig's I/O (the Python device, the firmware in simavr and the in-process rig), and
where its truth file is opened, with or without a patient."""

from __future__ import annotations

from pathlib import Path
from typing import Any

from rehab_hil.devices.plant_io import PlantIO
from rehab_hil.interfaces import DeviceBinding
from rehab_hil.patient.attach import TRUTH_SIGNALS, with_patient
from rehab_hil.patient.profile import load_patient
from rehab_hil.patient.truth import TruthWriter
from rehab_hil.plants.registry import get_plant
from rehab_hil.plants.thermal import temperature_signal

__all__ = ["patient_plant", "truth_signals"]


def truth_signals(cfg: Any, patient: bool) -> tuple[str, ...]:
    """What ``sim_truth.csv`` holds besides time: the primary axis's true angle and velocity, the heated
    actuator's true temperature (the plant's own signal, e.g. ``sma_temperature_c``: what no rig
    measures and the safety estimates), and with a patient the patient's true state."""
    ports = get_plant(cfg.plant).ports(cfg)
    axis = (ports.axes[0].angle, ports.axes[0].velocity) if ports.axes else ()
    temp = temperature_signal(ports)
    return (*axis, *((temp,) if temp else ()), *(TRUTH_SIGNALS if patient else ()))


def patient_plant(cfg: Any, binding: DeviceBinding, patient: Any, truth: str | Path | None = None,
                  **plant_io: Any) -> PlantIO:
    """``PlantIO`` on ``binding``, with the patient ``patient`` on its plant (a file, or a profile a session
    has loaded already; None: none) and its true state written to ``truth`` (``sim_truth.csv``,
    ``truth_signals``; None: not written). The writer is ``plant.truth_sink`` (close it with the device)."""
    if patient is not None:
        profile = load_patient(patient) if isinstance(patient, str | Path) else patient
        binding = with_patient(binding, cfg, profile)
    names = truth_signals(cfg, patient is not None)
    sink = TruthWriter(truth, names) if truth is not None else None
    return PlantIO(binding, truth_signals=names if sink else (), truth_sink=sink, **plant_io)
