"""Per-patient session profiles: a small TOML that sets a patient's exercise and tightens the rig's limits.

A profile may set the range of motion (``[limits] min_angle_deg`` / ``max_angle_deg``), the force
limit (``[limits] max_force_n``), the pace (``[session] cycles_per_minute``) and the movement
(``[session] closed_deg`` and ``amplitude_deg``: the session opens to closed + amplitude). It
overrides the plant config's ``[rig.session]`` and ``[rig.limits]`` but may only tighten the
limits, never widen them, and the movement must lie inside the resulting range. Errors name the
profile file and the key. Example: ``profiles/example.toml``; used by ``rehab-hil run --profile``.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from pydantic import Field

from rehab_hil.config import ConfigError, Section, load_toml, validate
from rehab_hil.plants.sections import PlantConfig

__all__ = ["Profile", "ProfileLimits", "ProfileSession", "apply_profile", "load_profile", "profile_rig_keys",
           "profile_summary"]


class ProfileSession(Section):
    """The patient's exercise: pace and movement (degrees of the encoder angle)."""

    cycles_per_minute: float | None = Field(default=None, gt=0.0, le=120.0)
    closed_deg: float | None = Field(default=None, ge=-360.0, le=360.0, description="start/return angle")
    amplitude_deg: float | None = Field(default=None, gt=0.0, le=360.0, description="open = closed + amplitude")


class ProfileLimits(Section):
    """The patient's limits: each must be inside the rig's own (tighten only)."""

    min_angle_deg: float | None = Field(default=None, ge=-360.0, le=360.0)
    max_angle_deg: float | None = Field(default=None, ge=-360.0, le=360.0)
    max_force_n: float | None = Field(default=None, gt=0.0, le=1000.0)


class Profile(Section):
    """A profile file: who it is for, and what it changes."""

    patient_id: str = Field(min_length=1, max_length=64, description="a pseudonymous label, never a name")
    note: str = Field(default="", max_length=500)
    session: ProfileSession = Field(default_factory=ProfileSession)
    limits: ProfileLimits = Field(default_factory=ProfileLimits)


def load_profile(path: str | Path) -> Profile:
    """Read and validate a profile file (``ConfigError`` naming file and key)."""
    return validate(path, load_toml(path), Profile)


def apply_profile(cfg: PlantConfig, profile: Profile, config_path: str | Path, profile_path: str | Path) -> PlantConfig:
    """The config with the profile's limits and session applied; refuses (``ConfigError`` on the
    profile's key) a limit wider than the rig's and a movement outside the range of motion."""
    lim, ses = cfg.rig.limits, cfg.rig.session
    pl, ps = profile.limits, profile.session

    def widen(key: str, value: float, rig_value: float, unit: str) -> ConfigError:
        return ConfigError(profile_path, key, f"{value:g} {unit} widens the rig's rig.{key} = {rig_value:g} {unit} "
                           f"({config_path}); a profile may only tighten the limits")

    if pl.min_angle_deg is not None and pl.min_angle_deg < lim.min_angle_deg:
        raise widen("limits.min_angle_deg", pl.min_angle_deg, lim.min_angle_deg, "deg")
    if pl.max_angle_deg is not None and pl.max_angle_deg > lim.max_angle_deg:
        raise widen("limits.max_angle_deg", pl.max_angle_deg, lim.max_angle_deg, "deg")
    if pl.max_force_n is not None and pl.max_force_n > lim.max_force_n:
        raise widen("limits.max_force_n", pl.max_force_n, lim.max_force_n, "N")
    new_lim = lim.model_copy(update={k: v for k, v in pl.model_dump().items() if v is not None})
    if new_lim.min_angle_deg >= new_lim.max_angle_deg:
        raise ConfigError(profile_path, "limits", f"min_angle_deg {new_lim.min_angle_deg:g} must be below "
                          f"max_angle_deg {new_lim.max_angle_deg:g}")
    update: dict[str, Any] = {"limits": new_lim}
    if any(v is not None for v in ps.model_dump().values()):
        if ses is None:
            raise ConfigError(profile_path, "session", f"{config_path} has no [rig.session] to adjust")
        closed = ps.closed_deg if ps.closed_deg is not None else ses.closed_deg
        opened = closed + ps.amplitude_deg if ps.amplitude_deg is not None else ses.open_deg
        host = cfg.rig.model_copy(update={"limits": new_lim}).host_limits()  # the profile's limits less the margins
        lo, hi = host.min_angle_deg, host.max_angle_deg
        for key, angle in (("session.closed_deg", closed), ("session.amplitude_deg", opened)):
            if not lo <= angle <= hi:
                what = "closed" if key.endswith("closed_deg") else "open (closed + amplitude)"
                raise ConfigError(profile_path, key, f"the {what} angle {angle:g} deg is outside the range of motion "
                                  f"{lo:g}..{hi:g} deg (limits inside the host margin)")
        new_ses = ses.model_copy(update={"closed_deg": closed, "open_deg": opened,
                                         **({"cycles_per_minute": ps.cycles_per_minute}
                                            if ps.cycles_per_minute is not None else {})})
        update["session"] = new_ses
    return cfg.model_copy(update={"rig": cfg.rig.model_copy(update=update)})


def profile_summary(profile: Profile, path: str | Path) -> dict[str, Any]:
    """What a session's metadata records about the profile in use."""
    return {"file": str(path), "patient_id": profile.patient_id, **{
        f"{section}.{k}": v for section in ("session", "limits")
        for k, v in getattr(profile, section).model_dump().items() if v is not None}}


# the rig keys a profile's keys set (config key -> the profile's key), for messages naming the cause
_RIG_KEYS = {"session.cycles_per_minute": ("rig.session.cycles_per_minute",),
             "session.closed_deg": ("rig.session.closed_deg", "rig.session.open_deg"),
             "session.amplitude_deg": ("rig.session.open_deg",),
             "limits.min_angle_deg": ("rig.limits.min_angle_deg",),
             "limits.max_angle_deg": ("rig.limits.max_angle_deg",),
             "limits.max_force_n": ("rig.limits.max_force_n",)}


def profile_rig_keys(profile: Profile) -> dict[str, str]:
    """The plant config's keys this profile overrides -> the profile's own key (a refusal names
    the profile's key when the profile set what causes it)."""
    out: dict[str, str] = {}
    for key, rig_keys in _RIG_KEYS.items():
        section, name = key.split(".")
        if getattr(getattr(profile, section), name) is not None:
            for rk in rig_keys:
                out.setdefault(rk, key)
    return out
