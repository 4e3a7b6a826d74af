"""Who a session is about, computed once per session and used by every store and the metadata.

The rig is its rig id; a simulated rig that runs another plant file is another rig (``-sim-`` and the
file's hash). The patient is a profile's ``patient_id`` (a person on a real rig) or a simulated patient
(``sim-`` its id and its file's hash: two files with one id are two patients); a profile and a simulated
patient together name both. A table learned with one patient is never used with another: every store
keys on ``SessionIdentity.rig`` and ``.patient``, each through ``store_name`` (one file name per identity).
"""

from __future__ import annotations

import hashlib
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from rehab_hil.outputs import name_part

__all__ = ["NO_PATIENT", "SessionIdentity", "file_hash", "store_name"]


def file_hash(path: str | Path) -> str:
    """The first 12 hex digits of a file's sha256 (what makes two files with one name two things)."""
    return hashlib.sha256(Path(path).read_bytes()).hexdigest()[:12]


NO_PATIENT = "no-patient"  # a store's name for a session that named nobody (no profile, no simulated patient)


def store_name(text: str | None) -> str:
    """``text`` (a rig or a patient of ``SessionIdentity``) as a store's file or folder name: readable, and
    one name per text. ``outputs.name_part`` alone folds "a b" and "a-b" into one name, and a patient whose
    id is "no-patient" would have taken the store of a session with nobody; the text's hash keeps them
    apart. None: ``NO_PATIENT``."""
    if text is None:
        return NO_PATIENT
    return f"{name_part(text)}-{hashlib.sha256(text.encode()).hexdigest()[:8]}"


@dataclass(frozen=True)
class SessionIdentity:
    """The rig and the patient of a session (``patient`` None: nobody named)."""

    rig: str
    patient: str | None

    @classmethod
    def of(cls, rig_id: str, sim_plant: Path | None = None, profile: Any = None, sim_patient: Any = None,
           sim_patient_path: Path | None = None) -> SessionIdentity:
        """From the loaded profile (``profiles.Profile``) and simulated patient (``patient.profile``)."""
        rig = rig_id + (f"-sim-{file_hash(sim_plant)}" if sim_plant is not None else "")
        who = []
        if profile is not None:
            who.append(profile.patient_id)
        if sim_patient is not None:
            digest = file_hash(sim_patient_path) if sim_patient_path is not None else "0"
            who.append(f"sim-{sim_patient.patient_id}-{digest}")
        return cls(rig, "+".join(who) if who else None)

    def metadata(self) -> dict[str, Any]:
        """metadata.json's ``identity``: what the stores were keyed on."""
        return {"rig": self.rig, "patient": self.patient}
