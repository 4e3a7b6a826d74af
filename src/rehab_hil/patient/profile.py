"""A simulated patient: ``PATIENT.toml`` (``profiles/sim/``), read and validated here.

Tables (SI units in every key): ``[voluntary]`` (the capacity per direction and the patient's own
position loop), optional ``[cue]``, ``[slacking]``, ``[fatigue]``, ``[passive]``, ``[spasticity]``
and ``[recovery]``; a table left out is a trait the patient does not have. Errors name the file
and the key (``ConfigError``).
"""

from __future__ import annotations

from pathlib import Path

from pydantic import Field

from rehab_hil.config import Section, load_toml, validate

__all__ = ["PatientProfile", "load_patient"]


class CueSection(Section):
    """How the patient sees the task's target."""

    reaction_s: float = Field(default=0.2, ge=0.0, le=2.0, description="the cue seen this late [s]")


class VoluntarySection(Section):
    """Voluntary torque toward the target, with a capacity per direction (at the MCP joint)."""

    flexion_capacity_nm: float = Field(ge=0.0, le=10.0, description="largest voluntary flexing torque [N m]")
    extension_capacity_nm: float = Field(ge=0.0, le=10.0, description="largest voluntary extending torque [N m]")
    stiffness_nm_per_rad: float = Field(ge=0.0, le=100.0, description="the patient's own position loop [N m/rad]")
    damping_nm_s_per_rad: float = Field(default=0.0, ge=0.0, le=10.0, description="its damping [N m s/rad]")
    integral_nm_per_rad_s: float = Field(default=0.0, ge=0.0, le=100.0, description="its action on the error's "
                                         "integral: closes a steady shortfall [N m/(rad s)]")
    integral_limit_rad_s: float = Field(default=0.2, gt=0.0, le=10.0, description="the integral held within [rad s]")


class SlackingSection(Section):
    """Effort that falls while assisted (Emken et al. 2007)."""

    slack_time_s: float = Field(gt=0.0, le=3600.0, description="effort decays with this time constant [s]")
    error_gain_per_rad_s: float = Field(ge=0.0, le=1000.0, description="effort regained per rad of error per s")
    effort_min: float = Field(default=0.0, ge=0.0, le=1.0, description="the least effort [0..1]")


class FatigueSection(Section):
    """Three-compartment fatigue (Xia & Frey Law 2008)."""

    fatigue_per_s: float = Field(ge=0.0, le=10.0, description="F: active -> fatigued [1/s]")
    recovery_per_s: float = Field(ge=0.0, le=10.0, description="R: fatigued -> resting [1/s]")
    rest_recovery_factor: float = Field(default=1.0, ge=1.0, le=100.0, description="r: R x r while relaxing")
    develop_per_s: float = Field(default=10.0, gt=0.0, le=1000.0, description="L_D: recruitment rate [1/s]")
    relax_per_s: float = Field(default=10.0, gt=0.0, le=1000.0, description="L_R: relaxation rate [1/s]")


class PassiveSection(Section):
    """The passive finger, double-exponential in the flexion angle (Kuo & Deshpande 2012)."""

    rest_flexion_rad: float = Field(ge=-1.0, le=2.5, description="flexion where the passive torque is zero [rad]")
    extension_scale_nm: float = Field(ge=0.0, le=5.0, description="[N m]")
    extension_shape_per_rad: float = Field(ge=0.0, le=50.0, description="[1/rad]")
    flexion_scale_nm: float = Field(ge=0.0, le=5.0, description="[N m]")
    flexion_shape_per_rad: float = Field(ge=0.0, le=50.0, description="[1/rad]")
    damping_nm_s_per_rad: float = Field(default=0.0, ge=0.0, le=1.0, description="[N m s/rad]")


class SpasticitySection(Section):
    """A velocity-dependent stretch reflex of the flexors (Lance 1980)."""

    threshold_rad_s: float = Field(ge=0.0, le=50.0, description="extension speed where the reflex starts [rad/s]")
    gain_nm_s_per_rad: float = Field(ge=0.0, le=10.0, description="flexing torque per rad/s above it [N m s/rad]")
    delay_s: float = Field(default=0.04, ge=0.001, le=0.099, description="reflex delay [s]")


class RecoverySection(Section):
    """Recovery across sessions: the capacity grows by a share per session done."""

    sessions_done: int = Field(default=0, ge=0, le=1000)
    capacity_gain_per_session: float = Field(default=0.0, ge=0.0, le=1.0, description="[share per session]")
    capacity_ceiling_nm: float = Field(default=3.0, gt=0.0, le=10.0, description="the healthy capacity [N m]")


class PatientProfile(Section):
    """One simulated patient."""

    patient_id: str = Field(min_length=1, max_length=64, description="a label, never a name")
    note: str = Field(default="", max_length=500)
    voluntary: VoluntarySection
    cue: CueSection = Field(default_factory=CueSection)
    slacking: SlackingSection | None = None
    fatigue: FatigueSection | None = None
    passive: PassiveSection | None = None
    spasticity: SpasticitySection | None = None
    recovery: RecoverySection | None = None

    def capacity_nm(self) -> tuple[float, float]:
        """(flexion, extension) capacity after the sessions done [N m]."""
        v, rec = self.voluntary, self.recovery
        if rec is None:
            return v.flexion_capacity_nm, v.extension_capacity_nm
        grow = (1.0 + rec.capacity_gain_per_session) ** rec.sessions_done
        return (min(v.flexion_capacity_nm * grow, max(rec.capacity_ceiling_nm, v.flexion_capacity_nm)),
                min(v.extension_capacity_nm * grow, max(rec.capacity_ceiling_nm, v.extension_capacity_nm)))


def load_patient(path: str | Path) -> PatientProfile:
    """Read and validate a patient file (``ConfigError`` naming file and key)."""
    return validate(path, load_toml(path), PatientProfile)
