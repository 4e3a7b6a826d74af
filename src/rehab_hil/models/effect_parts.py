"""Model parts for candidate effects that the plant models do not already provide.

Each is a small ``Part`` whose magnitude parameters at zero make it the identity (a wire) or a
zero torque/heat, so one diagram can carry every candidate disabled and the workflow enables
them by editing the parameter vector. Friction reuses ``models.mechanics``.
"""

from __future__ import annotations

import math

from rehab_hil.models.system import Part, njit

__all__ = ["DELAY_SLOTS", "ActuatorDeadZone", "Backlash", "ContactSpringDamper", "DirectionalCoulombFriction",
           "DirectionalViscousFriction", "NonlinearConvection", "PassiveMuscle", "SensorCreepHysteresis",
           "SensorGainOffset", "SmaHysteresis", "TransportDelay"]

DELAY_SLOTS = 64  # FIFO length of TransportDelay: the longest delay is (DELAY_SLOTS - 1) steps


class TransportDelay(Part):
    """y(t) = u(t - delay): a FIFO of past samples, linearly interpolated between slots so the
    output is continuous in ``delay_s`` (seed 002 sec 4.2: the hardware lags the simulation)."""

    inputs = ("u",)
    discrete_states = tuple(f"u_past_{i}" for i in range(DELAY_SLOTS))
    outputs = ("y",)
    params = ("delay_s", "step_s")

    @staticmethod
    @njit
    def output(t, x, xd, u, p, y):
        d = p[0] / p[1]
        if d <= 0.0:
            y[0] = u[0]
            return
        d = min(d, DELAY_SLOTS - 1.0)
        i0 = int(d)  # d > 0: truncation is floor
        f = d - i0
        v0 = u[0] if i0 == 0 else xd[i0 - 1]
        y[0] = (1.0 - f) * v0 + f * xd[i0]

    @staticmethod
    @njit
    def update(t, x, xd, u, p, xd_next):
        for i in range(DELAY_SLOTS - 1, 0, -1):
            xd_next[i] = xd[i - 1]
        xd_next[0] = u[0]


class Backlash(Part):
    """Play of total width ``width_rad`` between a drive angle and the angle that is measured:
    the driven side follows only once the gap is taken up (classic backlash operator)."""

    inputs = ("angle_rad",)
    discrete_states = ("held_angle_rad",)
    outputs = ("angle_rad",)
    params = ("width_rad",)

    @staticmethod
    @njit
    def output(t, x, xd, u, p, y):
        h = 0.5 * p[0]
        y[0] = min(max(xd[0], u[0] - h), u[0] + h)

    @staticmethod
    @njit
    def update(t, x, xd, u, p, xd_next):
        h = 0.5 * p[0]
        xd_next[0] = min(max(xd[0], u[0] - h), u[0] + h)


class ContactSpringDamper(Part):
    """One-sided contact: past ``contact_angle_rad`` a spring-damper pushes back, never pulls
    (seed 000 eq 18-28: the human-machine contact force as k dx + c dx'; k, c by regression)."""

    inputs = ("angle_rad", "velocity_rad_s")
    outputs = ("torque_nm",)
    params = ("stiffness_nm_per_rad", "damping_nm_s_per_rad", "contact_angle_rad")

    @staticmethod
    @njit
    def output(t, x, xd, u, p, y):
        pen = u[0] - p[2]
        if pen <= 0.0:
            y[0] = 0.0
            return
        y[0] = min(0.0, -(p[0] * pen + p[1] * u[1]))


class PassiveMuscle(Part):
    """Passive resistance of the finger's muscles and tendons: exponential in joint angle
    (seed 000 eq 1-3, the Hill parallel element) plus a viscous part; opposes flexion."""

    inputs = ("angle_rad", "velocity_rad_s")
    outputs = ("torque_nm",)
    params = ("scale_nm", "shape_per_rad", "damping_nm_s_per_rad")

    @staticmethod
    @njit
    def output(t, x, xd, u, p, y):
        a = max(u[0], 0.0)
        y[0] = -(p[0] * (math.exp(p[1] * a) - 1.0) + p[2] * u[1])


class SmaHysteresis(Backlash):
    """Transformation hysteresis of an SMA wire (seed 000 eq 14-17: austenite start/finish on
    heating lie above martensite start/finish on cooling): a play operator of width ``width_c``
    on the wire temperature the constitutive model sees, so heating sees T - width/2 and
    cooling T + width/2 once the direction has reversed. The same operator as ``Backlash``,
    on a temperature instead of an angle: only the port and parameter names differ."""

    inputs = ("temperature_c",)
    discrete_states = ("held_temperature_c",)
    outputs = ("temperature_c",)
    params = ("width_c",)


class NonlinearConvection(Part):
    """Extra heat loss growing with the cube of the temperature rise (seed 000 eq 13,
    h = h1 + h2 T^2; seed 001 blames nonlinear heat transfer for error growing with power).

    It reads the temperature sampled at the previous step (a 1 ms hold against thermal time
    constants of seconds), so summing its output into a feedthrough thermal model makes no loop."""

    inputs = ("temperature_c",)
    discrete_states = ("held_temperature_c",)
    outputs = ("heat_w",)
    params = ("coefficient_w_per_k3", "ambient_c")
    feedthrough = False

    @staticmethod
    @njit
    def output(t, x, xd, u, p, y):
        rise = xd[0] - p[1]
        y[0] = -p[0] * rise * rise * abs(rise)

    @staticmethod
    @njit
    def update(t, x, xd, u, p, xd_next):
        xd_next[0] = u[0]


class ActuatorDeadZone(Part):
    """Dead zone of a PWM power stage, both signs: commands within ``width_duty`` (a fraction of
    full-scale duty, times ``scale`` in the actuator's unit) give nothing, larger ones lose it,
    y = u - w sgn(u) for |u| > w (the classic dead-zone model of Tao & Kokotovic, "Adaptive control
    of systems with actuator and sensor nonlinearities", 1996; an H-bridge's dead time and a
    MOSFET's threshold make one, and a geared motor's brush friction adds to it)."""

    inputs = ("u",)
    outputs = ("y",)
    params = ("width_duty", "scale")

    @staticmethod
    @njit
    def output(t, x, xd, u, p, y):
        w = p[0] * p[1]
        if u[0] > w:
            y[0] = u[0] - w
        elif u[0] < -w:
            y[0] = u[0] + w
        else:
            y[0] = 0.0


class SensorGainOffset(Part):
    """Calibration drift of an ADC sensor: measured = (1 + gain_error_fraction) true + offset,
    the offset in ADC counts (``counts_per_unit`` converts). On a sensor that measures a plant
    input (a torque the patient applies, recorded and replayed), ``invert`` = 1 gives the true
    input the model must see: true = (measured - offset) / (1 + gain error). A Flexiforce's sensitivity drifts
    with temperature and load time and its zero with the mounting preload (Tekscan FlexiForce
    user manual: linearity, drift and repeatability; seed 000 sec III.A reads its contact force
    from one); a strain-gauge torque sensor's zero drifts with temperature."""

    inputs = ("u",)
    outputs = ("y",)
    params = ("gain_error_fraction", "offset_counts", "counts_per_unit", "invert")
    sensor_effect = True  # takes a measured signal over (effects.attach)

    @staticmethod
    @njit
    def output(t, x, xd, u, p, y):
        if p[3] > 0.5:
            y[0] = (u[0] - p[1] / p[2]) / (1.0 + p[0])
        else:
            y[0] = (1.0 + p[0]) * u[0] + p[1] / p[2]


class SensorCreepHysteresis(Part):
    """Creep and loading/unloading hysteresis of a piezoresistive force sensor (FlexiForce A201):
    measured = play_w(true) + c z, dz/dt = (true - z) / tau. After a load step the reading creeps
    by a fraction c of the load with time constant tau; unloading reads w above loading at the same
    load (a play operator of width w, in ADC counts: ``counts_per_unit`` converts). Identified on
    Dickmann et al. 2021's dead-weight staircases (``analysis/flexiforce.py``: tau 4.7-5.9 s, ~3 %
    in 5 s); Tekscan FlexiForce user manual (drift, hysteresis). On a sensor that measures a plant
    input (``invert`` = 1) the creep is removed (true = measured - c z, z following the true value);
    a play cannot be inverted uniquely, so there the hysteresis is not modelled."""

    inputs = ("u",)
    states = ("creep",)
    discrete_states = ("held",)
    outputs = ("y",)
    params = ("creep_fraction", "creep_time_s", "hysteresis_counts", "counts_per_unit", "invert")
    sensor_effect = True

    @staticmethod
    @njit
    def output(t, x, xd, u, p, y):
        if p[4] > 0.5:
            y[0] = u[0] - p[0] * x[0]
            return
        h = 0.5 * p[2] / p[3]
        y[0] = min(max(xd[0], u[0] - h), u[0] + h) + p[0] * x[0]

    @staticmethod
    @njit
    def derivatives(t, x, xd, u, p, dx):
        true = u[0] - p[0] * x[0] if p[4] > 0.5 else u[0]
        dx[0] = (true - x[0]) / p[1]

    @staticmethod
    @njit
    def update(t, x, xd, u, p, xd_next):
        h = 0.5 * p[2] / p[3]
        xd_next[0] = min(max(xd[0], u[0] - h), u[0] + h)


class DirectionalCoulombFriction(Part):
    """Coulomb friction whose level depends on the direction of motion: ``level_pos_nm`` against
    positive velocity, ``level_neg_nm`` against negative (a servo's brushes and seals, a preloaded
    screw: 0.030 N m one way and 0.012 N m the other on a small servo, issue 38). Karnopp stiction as
    ``mechanics.coulomb_torque``: inside the stick band it holds the other torques up to the level of
    the direction they push towards. Equal levels are ``CoulombFriction``; the difference of the two
    levels acts like a constant load while the axis moves."""

    inputs = ("velocity_rad_s", "other_torque_nm")
    outputs = ("torque_nm",)
    params = ("level_pos_nm", "level_neg_nm", "stick_velocity_rad_s", "stick_damping_nm_s_per_rad")

    @staticmethod
    @njit
    def output(t, x, xd, u, p, y):
        v = u[0]
        if v > p[2]:
            y[0] = -p[0]
            return
        if v < -p[2]:
            y[0] = p[1]
            return
        hold = -u[1] - p[3] * v  # positive: the others push the axis the negative way
        y[0] = min(max(hold, -p[0]), p[1])


class DirectionalViscousFriction(Part):
    """Viscous friction with a damping per direction of motion: -b+ omega for omega > 0, -b- omega
    for omega < 0 (a seal that drags more one way)."""

    inputs = ("velocity_rad_s",)
    outputs = ("torque_nm",)
    params = ("damping_pos_nm_s_per_rad", "damping_neg_nm_s_per_rad")

    @staticmethod
    @njit
    def output(t, x, xd, u, p, y):
        y[0] = -(p[0] if u[0] > 0.0 else p[1]) * u[0]
