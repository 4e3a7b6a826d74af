"""A patient on a plant: the patient's parts wired onto the plant's primary axis, the way effects
attach (by port, not by name), and a simulated rig's binding with them.

The torques of the voluntary drive, the passive finger and the stretch reflex are summed on
``PATIENT_TORQUE`` and enter the plant where its ports say (``Ports.interaction``: the Finger
Extensor's ``patient_torque_nm``, where its torque sensor reads it) or on the axis's torque sum
(the SMA and TCP fingers' MCP joint). The task's cue runs on ``SESSION_TIME``, the device's session
clock (``PlantIO`` feeds it), from the plant config's ``[rig.session]``: the host's reference and
the patient's target come from the same table. Only a simulated device builds this: the host's
model has no patient.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np

from rehab_hil.interfaces import DeviceBinding
from rehab_hil.models.mechanics import TorsionSpring, ViscousFriction
from rehab_hil.models.ports import Ports
from rehab_hil.models.sensors import Gain
from rehab_hil.models.stability import fastest_mode, substeps_for
from rehab_hil.models.system import Diagram, Part
from rehab_hil.patient.parts import (
    PassiveFinger,
    SlackingEffort,
    StretchReflex,
    TaskCue,
    ThreeCompartmentFatigue,
    VoluntaryDemand,
)
from rehab_hil.patient.profile import PatientProfile
from rehab_hil.plants.registry import get_plant
from rehab_hil.plants.sections import PlantConfig

__all__ = ["PATIENT_TORQUE", "SESSION_TIME", "TRUTH_SIGNALS", "flexion_frame", "patient_parts", "stable_substeps",
           "with_patient"]

SESSION_TIME = "session_time_s"  # the device's session clock [s], an input PlantIO sets every tick
PATIENT_TORQUE = "patient_axis_torque_nm"  # everything the patient puts on the axis [N m]
# what the simulated device writes to sim_truth.csv (besides time): the patient's true state
TRUTH_SIGNALS = ("patient_cue_rad", "patient_effort", "patient_demand_nm", "patient_voluntary_nm",
                 "patient_capacity_fraction", "patient_target_load", "patient_passive_nm", "patient_reflex_nm",
                 PATIENT_TORQUE)


def flexion_frame(ports: Ports, cfg: PlantConfig, rest_flexion_rad: float = 0.0) -> tuple[float, float]:
    """(sign, offset [rad]): the finger's flexion = sign x axis angle + offset.

    An MCP axis (the SMA exoskeleton, the TCP finger) measures the bend from where the device was
    fitted and homed: the patient's relaxed posture (``rest_flexion_rad``), as seed 000 measures its
    bending angle from the finger at rest and ``rehab-hil run --home current`` zeroes the encoder at
    the pose the finger is in; the plant's own passive finger (seed 000's Hill muscle and dorsal wire,
    seed 001's springs) rests there too. On a hand rig's other axis (the Finger Extensor's iris)
    opening extends the finger, straight at the session's open angle (an assumption: seed 002 gives
    no linkage)."""
    axis = ports.axes[0]
    if axis.finger:
        return 1.0, rest_flexion_rad
    return -1.0, math.radians(cfg.rig.session.open_deg) if cfg.rig.session is not None else 0.0


def _cue(cfg: PlantConfig, reaction_s: float) -> TaskCue:
    s = cfg.rig.session
    period = 60.0 / s.cycles_per_minute
    move = s.move_fraction * period
    hold = 0.5 * (period - 2.0 * move)  # as controllers.Reference.session: closed hold first
    return TaskCue("patient_cue", rename={"cue_rad": "patient_cue_rad"}, closed_rad=math.radians(s.closed_deg),
                   open_rad=math.radians(s.open_deg), move_s=move, hold_open_s=hold, hold_closed_s=hold,
                   offset_s=period - hold, reaction_s=reaction_s)


def patient_parts(ports: Ports, cfg: PlantConfig, patient: PatientProfile) -> list[Part]:
    """The patient's parts on the plant's primary axis (``ports.axes[0]``)."""
    if not ports.axes or cfg.rig.session is None:
        raise ValueError(f"plant {cfg.plant!r}: a simulated patient needs a joint axis and a [rig.session]")
    axis = ports.axes[0]
    ps = patient.passive
    sign, offset = flexion_frame(ports, cfg, ps.rest_flexion_rad if ps is not None else 0.0)
    flex_nm, ext_nm = patient.capacity_nm()
    pos_nm, neg_nm = (flex_nm, ext_nm) if sign > 0 else (ext_nm, flex_nm)  # capacity raising / lowering the angle
    v, sl = patient.voluntary, patient.slacking
    fa = patient.fatigue
    joint = {"angle_rad": axis.angle, "velocity_rad_s": axis.velocity}
    parts: list[Part] = [
        _cue(cfg, patient.cue.reaction_s),
        SlackingEffort("patient_slacking", connect={"cue_rad": "patient_cue_rad", "angle_rad": axis.angle},
                       rename={"effort": "patient_effort"}, x0=[1.0],
                       slack_time_s=sl.slack_time_s if sl else 0.0,
                       error_gain_per_rad_s=sl.error_gain_per_rad_s if sl else 0.0,
                       effort_min=sl.effort_min if sl else 1.0),
        VoluntaryDemand("patient_voluntary", connect={"cue_rad": "patient_cue_rad", **joint,
                                                      "effort": "patient_effort"},
                        rename={"demand_nm": "patient_demand_nm"}, kp_nm_per_rad=v.stiffness_nm_per_rad,
                        kd_nm_s_per_rad=v.damping_nm_s_per_rad, ki_nm_per_rad_s=v.integral_nm_per_rad_s,
                        integral_limit_rad_s=v.integral_limit_rad_s),
        ThreeCompartmentFatigue(
            "patient_fatigue", connect={"demand_nm": "patient_demand_nm"},
            rename={"torque_nm": "patient_voluntary_nm", "capacity_fraction": "patient_capacity_fraction",
                    "target_load": "patient_target_load"},
            fatigue_per_s=fa.fatigue_per_s if fa else 0.0, recovery_per_s=fa.recovery_per_s if fa else 0.0,
            rest_recovery_factor=fa.rest_recovery_factor if fa else 1.0,
            develop_per_s=fa.develop_per_s if fa else 10.0, relax_per_s=fa.relax_per_s if fa else 10.0,
            capacity_pos_nm=pos_nm, capacity_neg_nm=neg_nm),
        Gain("patient_voluntary_on_axis", connect={"u": "patient_voluntary_nm"}, rename={"y": PATIENT_TORQUE},
             gain=1.0),
    ]
    ps, sp = patient.passive, patient.spasticity
    parts.append(PassiveFinger(
        "patient_passive", connect=joint, rename={"torque_nm": "patient_passive_nm"}, flexion_sign=sign,
        offset_rad=offset, rest_flexion_rad=ps.rest_flexion_rad if ps else 0.0,
        extension_scale_nm=ps.extension_scale_nm if ps else 0.0,
        extension_shape_per_rad=ps.extension_shape_per_rad if ps else 0.0,
        flexion_scale_nm=ps.flexion_scale_nm if ps else 0.0,
        flexion_shape_per_rad=ps.flexion_shape_per_rad if ps else 0.0,
        damping_nm_s_per_rad=ps.damping_nm_s_per_rad if ps else 0.0))
    parts.append(StretchReflex(
        "patient_reflex", connect={"velocity_rad_s": axis.velocity}, rename={"torque_nm": "patient_reflex_nm"},
        flexion_sign=sign, threshold_rad_s=sp.threshold_rad_s if sp else 0.0,
        gain_nm_s_per_rad=sp.gain_nm_s_per_rad if sp else 0.0, delay_s=sp.delay_s if sp else 0.04,
        step_s=float(get_plant(cfg.plant).step(cfg)[0])))
    for name in ("patient_passive_nm", "patient_reflex_nm"):
        parts.append(Gain(f"{name[:-3]}_on_axis", connect={"u": name}, rename={"y": PATIENT_TORQUE}, gain=1.0))
    into, gain = ports.interaction if ports.interaction is not None else (axis.torque, 1.0)
    parts.append(Gain("patient_into_plant", connect={"u": PATIENT_TORQUE}, rename={"y": into}, gain=gain))
    return parts


def with_patient(binding: DeviceBinding, cfg: PlantConfig, patient: PatientProfile) -> DeviceBinding:
    """The simulated rig's binding with the patient on its plant: the patient's parts added, the
    session clock an input, the plant input the patient now drives no longer a constant."""
    ports = get_plant(cfg.plant).ports(cfg)
    parts = patient_parts(ports, cfg, patient)
    produced = {s for p in parts for s in p.signal_names}
    constants = {k: v for k, v in binding.constant_inputs.items() if k not in produced}
    return dataclasses.replace(binding, parts=[*binding.parts, *parts], constant_inputs={
        **constants, SESSION_TIME: 0.0}, sums=(*binding.sums, PATIENT_TORQUE),
        substeps=stable_substeps(binding, cfg, patient))


def stable_substeps(binding: DeviceBinding, cfg: PlantConfig, patient: PatientProfile) -> int:
    """The RK4 substeps the plant needs with the patient on it: while the patient's own loop acts
    directly (its recruitment ahead of its demand) its damping and stiffness load the axis, and on
    a light one (the TCP robotic finger's grams: a mode of ~8e3 1/s, |lambda h| 8 at 1 kHz) RK4 at
    the plant's own step rests in a spurious state. The plant with that load as a linear
    spring-damper on the axis (the patient's loop plus the passive finger's slope at the start),
    its fastest mode at rest (``models/stability.py``); the plant's own substeps at least."""
    ports = get_plant(cfg.plant).ports(cfg)
    axis = ports.axes[0]
    v, ps = patient.voluntary, patient.passive
    _, offset = flexion_frame(ports, cfg, ps.rest_flexion_rad if ps is not None else 0.0)
    k, b = v.stiffness_nm_per_rad, v.damping_nm_s_per_rad
    if ps is not None:
        d = offset - ps.rest_flexion_rad  # the flexion at the axis's zero against the rest
        k += ps.extension_scale_nm * ps.extension_shape_per_rad * math.exp(-ps.extension_shape_per_rad * d) \
            + ps.flexion_scale_nm * ps.flexion_shape_per_rad * math.exp(ps.flexion_shape_per_rad * d)
        b += ps.damping_nm_s_per_rad
    into, gain = ports.interaction if ports.interaction is not None else (axis.torque, 1.0)
    load = [TorsionSpring("load_spring", connect={"angle_rad": axis.angle}, rename={"torque_nm": "load_nm"},
                          stiffness_nm_per_rad=k, rest_angle_rad=0.0),
            ViscousFriction("load_damping", connect={"velocity_rad_s": axis.velocity}, rename={"torque_nm": "load_nm"},
                            damping_nm_s_per_rad=b),
            Gain("load_into_plant", connect={"u": "load_nm"}, rename={"y": into}, gain=gain)]
    inputs = (*binding.duty_inputs, *binding.constant_inputs)  # as the device's PlantIO compiles it
    system = Diagram([*binding.parts, *load], inputs=inputs, sums=(*binding.sums, "load_nm")).compile(
        binding.step_s, binding.substeps)
    u = np.array([binding.constant_inputs.get(name, 0.0) for name in system.input_names], float)
    return substeps_for(fastest_mode(system, u), binding.step_s, binding.substeps)
