"""What a session loads once and opens before anything moves: the config (with the profile), the binding,
the controller, the simulated patient, the session's identity; then the rig; then the features it asked for.

Everything is read here once and passed down (``Loaded``): the features, the rig and the stores never
load a file again.
"""

from __future__ import annotations

from contextlib import ExitStack
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from rehab_hil.config import ConfigError
from rehab_hil.controllers.build import Sources
from rehab_hil.hardware import RIG_KINDS, HardwareError, open_rig
from rehab_hil.loading import load_config
from rehab_hil.patient.profile import load_patient
from rehab_hil.patient.truth import SimTruth
from rehab_hil.plants import get_plant
from rehab_hil.plants.thermal import ActuatorThermal
from rehab_hil.profiles import apply_profile, load_profile, profile_rig_keys
from rehab_hil.protocol import Configure
from rehab_hil.service import assembly
from rehab_hil.service.errors import SessionError
from rehab_hil.service.features.assistance import KeptAssistanceFeature, assistance_directions
from rehab_hil.service.features.base import Feature, SessionParts
from rehab_hil.service.features.learning import RigLearningFeature, learning_wanted
from rehab_hil.service.features.recording import Recording
from rehab_hil.service.features.safety_thermal import SafetyThermalFeature
from rehab_hil.service.features.truth import SimTruthFeature
from rehab_hil.service.features.twin import PatientTorque, Twin
from rehab_hil.service.features.views import Foxglove, Telemetry
from rehab_hil.service.identity import SessionIdentity
from rehab_hil.service.options import SessionOptions

__all__ = ["Loaded", "load_session", "open_hardware", "session_features"]


@dataclass
class Loaded:
    """A session's files, read once: the config and what it gives, the patient, the controller."""

    config: Path
    device: str
    options: SessionOptions
    cfg: Any  # the profile applied
    binding: Any
    controller: Any
    configure: Configure
    device_cfg: Any  # the plant config the simulated device runs (``sim_plant``, else ``cfg``)
    device_config: Path
    identity: SessionIdentity
    rig_id: str
    patient: Any = None  # the simulated patient, loaded (``patient.profile``), or None
    truth: SimTruth | None = None


def load_session(config: Path, device: str | None, opts: SessionOptions) -> Loaded:
    """Every file the session needs, read and checked once; ``SessionError`` (one line) for a bad one."""
    profile = load_profile(opts.profile) if opts.profile is not None else None
    cfg = load_config(config)
    if profile is not None:
        cfg = apply_profile(cfg, profile, config, opts.profile)
    binding = get_plant(cfg.plant).device(cfg)
    device = device or cfg.rig.port
    sim = opts.sim
    patient = _sim_patient(sim.sim_patient, device, opts)
    device_cfg, device_config = _device_config(cfg, config, device, sim.sim_plant)
    tel = opts.views.telemetry
    rig_id = opts.rig.rig_id or (tel.rig_id if tel is not None else None) or cfg.plant
    identity = SessionIdentity.of(rig_id, sim.sim_plant, profile, patient, sim.sim_patient)
    sources = Sources(str(config)) if profile is None else Sources(str(config), str(opts.profile),
                                                                      profile_rig_keys(profile))
    return Loaded(config, device, opts, cfg, binding, _controller(cfg, config, opts, sources),
                  opts.test.configure or assembly.firmware_configure(cfg, binding), device_cfg, device_config,
                  identity, rig_id, patient)


def _controller(cfg: Any, config: Path, opts: SessionOptions, sources: Sources) -> Any:
    """The controller the loop steps: a declared one built by name for this plant, or the object given."""
    if opts.controller is not None and not isinstance(opts.controller, str):
        return opts.controller
    try:
        return assembly.build_controller(cfg, opts.controller, opts.reference, source=str(config), sources=sources)
    except assembly.ServiceSetupError as e:
        raise SessionError(None, f"{config}: {e}") from None


def _sim_patient(path: Path | None, device: str, opts: SessionOptions) -> Any:
    """The simulated patient (None: none); refused on a real board, and when it does not validate."""
    if path is None:
        return None
    if device not in RIG_KINDS or opts.rig.hw is not None:
        raise SessionError("sim_patient", f"for simulated devices ({', '.join(RIG_KINDS)}); device {device} is a "
                           "real board, whose patient is a person")
    try:
        return load_patient(path)
    except (ConfigError, OSError) as e:
        raise SessionError("sim_patient", str(e)) from None


def _device_config(cfg: Any, config: Path, device: str, sim_plant: Path | None) -> tuple[Any, Path]:
    """The plant config a simulated device runs: ``sim_plant`` (the same plant, maybe with effects the
    host's model lacks) or the host's own."""
    if sim_plant is None:
        return cfg, config
    if device not in RIG_KINDS:
        raise SessionError("sim_plant", f"for simulated devices ({', '.join(RIG_KINDS)}); device {device} is a "
                           "real board, whose plant is the physical one")
    dev = load_config(sim_plant)
    if dev.plant != cfg.plant:
        raise SessionError("sim_plant", f"{sim_plant}: a {dev.plant!r} plant; the host's config {config} is a "
                           f"{cfg.plant!r} plant")
    return dev, sim_plant


def open_hardware(stack: ExitStack, loaded: Loaded) -> SessionParts:
    """Open and connect the rig (a simulated one's process stops with the stack); a simulated rig's truth
    file first (a simulated patient's session, or any recorded one), so it is moved after the device
    has closed it."""
    opts = loaded.options
    simulated = loaded.device in RIG_KINDS and opts.rig.hw is None
    if simulated and opts.views.record is not None:  # unrecorded: nothing to keep it in
        loaded.truth = SimTruth()
        stack.callback(loaded.truth.finish)
    hw = opts.rig.hw
    if hw is None:
        truth = loaded.truth.path if loaded.truth is not None else None
        try:
            hw = stack.enter_context(open_rig(
                loaded.device, loaded.device_config, lockstep=opts.lockstep, baud=loaded.cfg.rig.baud,
                write_timeout_s=loaded.cfg.rig.write_timeout_ms / 1000.0, sim_patient=opts.sim.sim_patient,
                sim_truth=truth, cfg=loaded.device_cfg, loaded_patient=loaded.patient))
        except HardwareError as e:
            raise SessionError("device", f"{loaded.device}: {e}") from None
    return SessionParts(loaded.cfg, loaded.config, loaded.binding, assembly.period_s(loaded.cfg), loaded.device, hw,
                        loaded.controller, opts, loaded.rig_id, loaded.identity,
                        opts.lockstep or loaded.device == "inprocess")


def session_features(loaded: Loaded, parts: SessionParts) -> list[Feature]:
    """The features the options ask for, in the order they open (each after those it reads)."""
    opts, cfg, controller = loaded.options, loaded.cfg, loaded.controller
    views = opts.views
    out: list[Feature] = []
    if assistance_directions(controller):
        out.append(KeptAssistanceFeature())
    if views.record is not None:
        out.append(Recording())
    if loaded.truth is not None:
        out.append(SimTruthFeature(loaded.truth))
    if views.telemetry is not None:
        out.append(Telemetry(views.telemetry))
    if views.foxglove is not None:
        out.append(Foxglove(views.foxglove))
    if views.twin or (cfg.twin is not None and cfg.twin.enabled):
        out += [Twin(), PatientTorque()]
    if hasattr(controller, "controller") and learning_wanted(controller, opts.learning.rig_learning):
        out.append(RigLearningFeature())
    if any(isinstance(f, Twin) for f in out) and ActuatorThermal.of(cfg) is not None:
        out.append(SafetyThermalFeature())  # after the learning: its hook tells the safety before the re-plan
    return out + list(opts.test.features)
