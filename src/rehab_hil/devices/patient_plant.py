"""The simulated device's plant with a patient on it: the one place ``--sim-patient`` turns into a
plant behind the rig's I/O (the Python device, the firmware in simavr and the in-process rig)."""

from __future__ import annotations

from pathlib import Path
from typing import Any

from rehab_hil.devices.plant_io import PlantIO
from rehab_hil.interfaces import DeviceBinding
from rehab_hil.patient.attach import TRUTH_SIGNALS, with_patient
from rehab_hil.patient.profile import load_patient
from rehab_hil.patient.truth import TruthWriter
from rehab_hil.plants.registry import get_plant

__all__ = ["patient_plant"]


def patient_plant(cfg: Any, binding: DeviceBinding, patient: Any, truth: str | Path | None = None,
                  **plant_io: Any) -> PlantIO:
    """``PlantIO`` on ``binding``, with the patient ``patient`` on its plant (a file, or a profile a session
    has loaded already; None: none) and its true state written to ``truth`` (``sim_truth.csv``; None: not
    written). The writer is ``plant.truth_sink`` (close it with the device)."""
    if patient is None:
        return PlantIO(binding, **plant_io)
    profile = load_patient(patient) if isinstance(patient, str | Path) else patient
    axis = get_plant(cfg.plant).ports(cfg).axes[0]
    names = (axis.angle, axis.velocity, *TRUTH_SIGNALS)
    sink = TruthWriter(truth, names) if truth is not None else None
    return PlantIO(with_patient(binding, cfg, profile), truth_signals=names if sink else (), truth_sink=sink,
                   **plant_io)
