"""An independent SMA-exoskeleton rig simulator for the discrepancy benchmark (issue 14, item 7).

``sma_independent_record`` makes records of the SMA-wire-driven finger exoskeleton of seed 000
(``/work/shared/seeds/000_4955e3f0c70b2423.txt``) that the project's models did not make: it imports
nothing from ``rehab_hil.models``, ``rehab_hil.plants``, ``rehab_hil.effects`` or
``rehab_hil.discrepancy``; it reads the nominal parameters straight from
``configs/sma_exoskeleton.toml`` with ``tomllib`` and returns a ``rehab_hil.interchange.Recording``.

Independent (own code, own formulation):

- finger: the eq-9-coupled 3-link chain (theta2 = 6/5 theta1, theta3 = 4/5 theta1) as one DOF whose
  effective inertia m(theta) = s^T M(s theta) s is built *numerically* from the link Jacobians
  (M = sum m_i Jv_i^T Jv_i + I_i Jw_i^T Jw_i, uniform rods, COM mid-link, I = m L^2 / 12), with the
  velocity term 1/2 m'(theta) theta'^2 from a central difference and the gravity torque from a
  central difference of the potential (gravity vector from the config, zero by default); all three
  tabulated on a 1 mrad grid and interpolated linearly (no closed-form M, no Christoffel symbols);
- integrator: own fixed-step three-stage SSP Runge-Kutta (Shu-Osher) at 0.5 ms (two sub-steps per
  1 kHz duty sample), not an RK4 engine; the martensite fraction is a hysteretic algebraic state
  updated once per sub-step: projected onto [xi_M*, xi_A*], the roots of xi = xi_branch(T, sigma(xi))
  solved with ``scipy.optimize.brentq`` only when xi leaves that band;
- stress written in recovery form sigma = E(xi) (eps_r (1 - xi) - e / l) + Theta (T - T0);
  pad deformation by the law of cosines; the fingertip lever summed link by link;
- the rig: the session is cut at a random 6-12 s into a run whose duty train began at t = 0 (hot
  wire, bent finger); random duty trains (duty 0.3-1.0, random pulse and rest lengths), or a PID
  of its own on the quantised MCP encoder angle tracking a random smooth MCP trajectory (5-35 deg,
  holds) at 1 kHz; MCP encoder quantised to 360/4096 deg; Flexiforce through a 10-bit ADC
  (counts_per_n from the config, 0.03 N noise before quantisation, clipped to 0..1023); logged at
  ``rate_hz``; ``supply_voltage_v`` logs the nominal 32 V even when the real supply differs;
- hidden effects with their own laws (see ``EFFECT_LAWS``), deliberately not the library's forms
  where a different realistic form exists, and two out-of-library errors (``prestrain``: functional
  fatigue; ``pad_creep``: viscoelastic relaxation of the pad).

Deliberately the same interpretation as the project (docs/sma_exoskeleton.md), so that a clean
record matches the project's model within sensor noise: eq 12-13 with h = h1 + h2 T^2 (T in degC);
Tanaka eq 14-17 integrated with Omega = -eps_p E, C_A read as 13.6 MPa/C, Liang-Rogers cosine
branches (heating A_s..A_f, cooling M_s..M_f from the Flexinol data) shifted by sigma / C_A, major-loop
hysteresis with flat minor loops, stress bounded to [0, sigma_max]; the passive wire eq 10-11 pulls
only; the Hill passive LE (eq 1-3) with l_N = rest ratio + (moment arms . joint angles) / L_o; the
massless-exoskeleton closure: the wires' torque on the coupled coordinate reaches the finger
through the fingertip pad, F = T_wires / (s^T J_tip^T n), the pad deformation phi is a state with
k d(phi) + c c_e phi' = F (signed Kelvin-Voigt), and the wires are strained by the finger's angles
plus phi spread over the joints 1 : 1.2 : 0.8 (normalised to sum 1); joint damping on all three
joints.
"""

from __future__ import annotations

import functools
import math
import tomllib
from collections.abc import Callable
from pathlib import Path

import numpy as np
from scipy.optimize import brentq

from rehab_hil.interchange import Recording

__all__ = ["EFFECT_LAWS", "ERRORS", "simulate", "sma_independent_record"]

ROOT = Path(__file__).resolve().parents[1]
CONFIG = ROOT / "configs" / "sma_exoskeleton.toml"
S = (1.0, 1.2, 0.8)  # seed 000 eq 9: theta2 = 6/5 theta1, theta3 = 2/3 theta2 = 4/5 theta1
PAD_SPREAD = tuple(w / sum(S) for w in S)  # the exoskeleton's extra bend phi over the joints, sum 1

EFFECT_LAWS: dict[str, tuple[tuple[str, ...], str]] = {  # name -> (parameters, law and source)
    "sma_hysteresis": (("width_c",), "A_s, A_f up by width/2 and M_s, M_f down by width/2: a wider major loop "
                       "(Liang & Rogers 1990, transformation temperatures shift with alloy/training)"),
    "passive_muscle": (("scale_nm", "shape_per_rad", "damping_nm_s_per_rad"),
                       "-scale (exp(shape theta) - 1) - damping theta' on the MCP, both signs of theta "
                       "(exponential passive joint moment, Kuo & Deshpande 2012, J. Biomech. Eng.)"),
    "contact_spring_damper": (("stiffness_nm_per_rad", "damping_nm_s_per_rad", "contact_angle_rad"),
                              "Hunt-Crossley K pen^1.5 + lambda pen^1.5 theta' past the angle, K and lambda such "
                              "that at pen = 0.1 rad the slope is k and the damping c; never pulls "
                              "(Hunt & Crossley 1975, J. Appl. Mech.)"),
    "actuator_dead_zone": (("width_duty",), "gate-drive dead time eats a fixed on-time per PWM period: "
                           "duty_eff = max(0, d - w) (MOSFET half-bridge dead time, e.g. TI SLUA618)"),
    "coulomb_friction": (("level_nm",), "-level tanh(theta' / 0.02 rad/s) on the MCP, no stick band "
                         "(smoothed Coulomb, Andersson et al. 2007)"),
    "viscous_friction": (("damping_nm_s_per_rad",), "extra viscous damping on all three joints, projected "
                         "through the coupling: -b (s.s) theta'"),
    "time_delay": (("delay_s",), "the wire's driver sees the duty delay_s late (bus / driver latency)"),
    "backlash": (("width_rad",), "play of total width between the MCP and the encoder shaft (dead-band "
                 "operator, Tao & Kokotovic 1996)"),
    "sensor_gain_offset": (("gain_error_fraction", "offset_counts"), "Flexiforce sensitivity drift and zero "
                           "offset before the ADC: (1 + g) F + offset / counts_per_n (Tekscan A201 manual)"),
}
ERRORS: dict[str, str] = {  # relative parameter errors and out-of-library effects
    "supply": "real supply = nominal (1 + e); the logged column stays nominal",
    "h1": "convection coefficient h1 (1 + e)",
    "muscle_f_o": "the LE's F_o (1 + e)",
    "prestrain": "out of library: functional fatigue, recoverable prestrain eps_p (1 + e) (e < 0: lower; "
                 "Eggeler et al. 2004, Mater. Sci. Eng. A)",
    "pad_creep": "out of library: the pad's stiffness relaxes k (1 - e (1 - exp(-t / 8 s))) over the run "
                 "(viscoelastic creep of TPU, standard-linear-solid relaxation)",
}

_TABLE_LO, _TABLE_HI, _TABLE_D = -1.0, 2.6, 0.001  # theta grid [rad] of the inertia tables


def _config() -> dict:
    with open(CONFIG, "rb") as f:
        return tomllib.load(f)


def _check(effects: dict[str, dict[str, float]], errors: dict[str, float]) -> None:
    for name, params in effects.items():
        if name not in EFFECT_LAWS:
            raise ValueError(f"unknown effect {name!r}; this generator knows {sorted(EFFECT_LAWS)}")
        unknown = set(params) - set(EFFECT_LAWS[name][0])
        if unknown:
            raise ValueError(f"effect {name!r}: unknown parameters {sorted(unknown)}; "
                             f"it takes {list(EFFECT_LAWS[name][0])}")
    for name in errors:
        if name not in ERRORS:
            raise ValueError(f"unknown error {name!r}; this generator knows {sorted(ERRORS)}")


# --- the finger: effective inertia from the link Jacobians, tabulated ----------------------------


def _finger_tables(fin: dict) -> tuple[list[float], list[float], list[float], list[float]]:
    """m(theta), m'(theta), G(theta) [gravity torque on theta] and the fingertip lever s^T J^T n on a
    grid of the coupled MCP angle: M(q) assembled from numerical link Jacobians (cached per finger)."""
    return _tables(tuple(sorted((k, float(v)) for k, v in fin.items())))


@functools.lru_cache(maxsize=8)
def _tables(items: tuple[tuple[str, float], ...]) -> tuple[list[float], list[float], list[float], list[float]]:
    fin = dict(items)
    L = np.array([fin["proximal_length_m"], fin["middle_length_m"], fin["distal_length_m"]])
    m = np.array([fin["proximal_mass_kg"], fin["middle_mass_kg"], fin["distal_mass_kg"]])
    inertia = m * L**2 / 12.0
    g = np.array([fin["gravity_x_m_s2"], fin["gravity_y_m_s2"]])
    s = np.array(S)

    def com_positions(q: np.ndarray) -> np.ndarray:
        """(3, 2) centres of mass for joint angles q (relative angles, flexion positive)."""
        phi = np.cumsum(q)
        out = np.zeros((3, 2))
        base = np.zeros(2)
        for i in range(3):
            u = np.array([math.cos(phi[i]), math.sin(phi[i])])
            out[i] = base + 0.5 * L[i] * u
            base = base + L[i] * u
        return out

    def mass_matrix(q: np.ndarray) -> np.ndarray:
        dq = 1e-6
        Jv = np.zeros((3, 2, 3))  # link, xy, joint: central differences of the COM positions
        for j in range(3):
            e = np.zeros(3)
            e[j] = dq
            Jv[:, :, j] = (com_positions(q + e) - com_positions(q - e)) / (2 * dq)
        M = np.zeros((3, 3))
        for i in range(3):
            Jw = np.array([1.0 if j <= i else 0.0 for j in range(3)])
            M += m[i] * Jv[i].T @ Jv[i] + inertia[i] * np.outer(Jw, Jw)
        return M

    def m_eff(theta: float) -> float:
        return float(s @ mass_matrix(s * theta) @ s)

    def potential(theta: float) -> float:
        return -float(np.sum(m * (com_positions(s * theta) @ g)))

    grid = np.arange(_TABLE_LO, _TABLE_HI + _TABLE_D / 2, _TABLE_D)
    d = 1e-4
    me = [m_eff(th) for th in grid]
    dme = [(m_eff(th + d) - m_eff(th - d)) / (2 * d) for th in grid]
    grav = [(potential(th + d) - potential(th - d)) / (2 * d) for th in grid] if np.any(g != 0.0) else [0.0] * grid.size
    lever = []
    for th in grid:  # fingertip force normal to the distal phalanx: dp_tip/dq_j . n, projected on s
        phi = np.cumsum(s * th)
        jn = [sum(L[i] * math.cos(phi[2] - phi[i]) for i in range(j, 3)) for j in range(3)]
        lever.append(float(s @ np.array(jn)))
    return me, dme, grav, lever


def _interp(table: list[float], theta: float) -> float:
    x = (theta - _TABLE_LO) / _TABLE_D
    i = int(x)
    if i < 0:
        i = 0
    elif i > len(table) - 2:
        i = len(table) - 2
    f = x - i
    return table[i] + f * (table[i + 1] - table[i])


# --- duty trains and references ----------------------------------------------------------------


def _duty_train(rng: np.random.Generator, n: int, dt: float) -> np.ndarray:
    """Heating pulses of random duty (0.3-1.0) and length (0.8-4 s), cooling rests (1-5 s), from t = 0."""
    duty = np.zeros(n)
    k = 0
    while k < n:
        on, off = rng.uniform(0.8, 4.0), rng.uniform(1.0, 5.0)
        level = float(rng.uniform(0.3, 1.0))
        k_on = k + round(on / dt)
        duty[k:k_on] = level
        k = k_on + round(off / dt)
    return duty


def _reference(rng: np.random.Generator, total_s: float) -> Callable[[float], float]:
    """Random smooth MCP trajectory [deg]: from 0, minimum-jerk moves (1-3 s) between holds (1-4 s)
    at random levels 5-35 deg."""
    knots: list[tuple[float, float, float, float]] = []  # (start, end, from, to)
    t, a = 0.5, 0.0
    while t < total_s + 2.0:
        move = rng.uniform(1.0, 3.0)
        b = float(rng.uniform(5.0, 35.0))
        knots.append((t, t + move, a, b))
        t += move + rng.uniform(1.0, 4.0)
        a = b

    def ref(time_s: float) -> float:
        val = 0.0
        for t0, t1, a0, b0 in knots:
            if time_s < t0:
                return val
            if time_s >= t1:
                val = b0
                continue
            x = (time_s - t0) / (t1 - t0)
            return a0 + (b0 - a0) * x * x * x * (10.0 - 15.0 * x + 6.0 * x * x)
        return val

    return ref


# --- the simulator -----------------------------------------------------------------------------


def simulate(effects: dict[str, dict[str, float]], errors: dict[str, float], duty: np.ndarray | None = None,
             *, n_steps: int | None = None, dt: float = 1e-3, substeps: int = 2,
             controller: Callable[[int, float], float] | None = None, state0: dict[str, float] | None = None,
             ) -> dict[str, np.ndarray]:
    """Run the rig for ``len(duty)`` (or ``n_steps``) duty samples of ``dt``; each sample integrated in
    ``substeps`` SSP-RK3 sub-steps. ``controller(k, measured_angle_deg) -> duty`` replaces ``duty``
    (closed loop; it sees the encoder angle through the backlash and quantisation). Returns the
    true signals sampled before each duty sample: ``t``, ``duty`` (commanded), ``theta_rad``,
    ``force_n`` (true contact force), ``temperature_c``, ``xi``, ``phi_rad``, ``encoder_rad``."""
    _check(effects, errors)
    cfg = _config()
    sma, drv, pw, ten, fin, mus, con = (cfg["sma"], cfg["drive"], cfg["passive_wire"], cfg["tendon"], cfg["finger"],
                                        cfg["muscle"], cfg["contact"])
    n = len(duty) if duty is not None else int(n_steps or 0)
    h = dt / substeps
    # thermal (eq 12-13)
    area_x = math.pi * sma["radius_m"] ** 2
    heat_cap = sma["density_kg_m3"] * area_x * sma["length_m"] * sma["specific_heat_j_per_kg_c"]
    r_ohm = sma["resistivity_ohm_m"] * sma["length_m"] / area_x
    surface = 2.0 * math.pi * sma["radius_m"] * sma["length_m"]
    u_real = drv["supply_voltage_v"] * (1.0 + errors.get("supply", 0.0))
    p_full = u_real * u_real / r_ohm
    h1 = sma["h1_w_per_m2_c"] * (1.0 + errors.get("h1", 0.0))
    h2 = sma["h2_w_per_m2_c3"]
    t0c = sma["ambient_c"]
    # Tanaka (eq 14-17)
    e_m, e_a, theta_te, c_a = (sma["martensite_modulus_pa"], sma["austenite_modulus_pa"],
                               sma["thermoelastic_pa_per_c"], sma["stress_influence_pa_per_c"])
    widen = 0.5 * effects.get("sma_hysteresis", {}).get("width_c", 0.0)
    a_s, a_f = sma["austenite_start_c"] + widen, sma["austenite_finish_c"] + widen
    m_s, m_f = sma["martensite_start_c"] - widen, sma["martensite_finish_c"] - widen
    eps_r = sma["prestrain"] * (1.0 + errors.get("prestrain", 0.0))
    sig_max = sma["max_stress_pa"]
    length = sma["length_m"]
    # passive wire (eq 10-11) and tendon (eq 5)
    k_pass = pw["martensite_modulus_pa"] * math.pi * pw["radius_m"] ** 2 / pw["length_m"]
    pre_pass = pw["pretension_n"]
    radii = (ten["mcp_radius_m"], ten["pip_radius_m"], ten["dip_radius_m"])
    r_theta = sum(r * s for r, s in zip(radii, S, strict=True))  # excursion per rad of the finger
    r_phi = sum(r * w for r, w in zip(radii, PAD_SPREAD, strict=True))  # per rad of the pad's bend
    # muscle (eq 1-3, fibre-length reading)
    shape = mus[mus["age_group"]]
    k_pe, e_o = shape["k_pe"], shape["e_o"]
    f_o = mus["max_isometric_force_n"] * (1.0 + errors.get("muscle_f_o", 0.0))
    arm = (mus["mcp_moment_arm_m"] * S[0] + mus["pip_moment_arm_m"] * S[1] + mus["dip_moment_arm_m"] * S[2])
    l_o, l_rest = mus["optimal_fibre_length_m"], mus["rest_length_ratio"]
    fl_den = math.exp(k_pe) - 1.0
    # finger (eq 29 with eq 9), damping on each joint
    me_t, dme_t, g_t, lev_t = _finger_tables(fin)
    ss = sum(s * s for s in S)
    b_joint = (fin["joint_damping_nm_s_per_rad"] + effects.get("viscous_friction", {}).get("damping_nm_s_per_rad",
                                                                                            0.0)) * ss
    # pad (eq 18-28)
    k_pad, c_pad, c_e, c_s = con["stiffness_n_per_m"], con["damping_n_s_per_m"], con["exo_radius_m"], con[
        "finger_radius_m"]
    gap0 = abs(c_e - c_s)
    creep = errors.get("pad_creep", 0.0)
    # hidden effects
    pm = effects.get("passive_muscle", {})
    pm_a, pm_b, pm_c = pm.get("scale_nm", 0.0), pm.get("shape_per_rad", 0.0), pm.get("damping_nm_s_per_rad", 0.0)
    hc = effects.get("contact_spring_damper", {})
    hc_k = hc.get("stiffness_nm_per_rad", 0.0) / (1.5 * math.sqrt(0.1))
    hc_c = hc.get("damping_nm_s_per_rad", 0.0) / 0.1**1.5
    hc_on = hc_k > 0.0 or hc_c > 0.0
    hc_angle = hc.get("contact_angle_rad", 0.0)
    fc = effects.get("coulomb_friction", {}).get("level_nm", 0.0)
    dead = effects.get("actuator_dead_zone", {}).get("width_duty", 0.0)
    delay = effects.get("time_delay", {}).get("delay_s", 0.0)
    play = effects.get("backlash", {}).get("width_rad", 0.0)
    v_tanh = 0.02

    def stress(xi: float, temp: float, exc: float) -> float:
        sig = (e_a + xi * (e_m - e_a)) * (eps_r * (1.0 - xi) - exc / length) + theta_te * (temp - t0c)
        return 0.0 if sig < 0.0 else (sig_max if sig > sig_max else sig)

    def branch(temp: float, sig: float, lo: float, hi: float) -> float:
        te = temp - sig / c_a
        if te <= lo:
            return 1.0
        if te >= hi:
            return 0.0
        return 0.5 + 0.5 * math.cos(math.pi * (te - lo) / (hi - lo))

    def consistent(temp: float, exc: float, lo: float, hi: float) -> float:
        def g(x: float) -> float:
            return x - branch(temp, stress(x, temp, exc), lo, hi)

        g0, g1 = g(0.0), g(1.0)
        if g0 >= 0.0:
            return 0.0
        if g1 <= 0.0:
            return 1.0
        return brentq(g, 0.0, 1.0, xtol=1e-12, rtol=1e-12)

    def martensite(xi: float, temp: float, exc: float) -> float:
        """Project xi onto the admissible band [xi_M*, xi_A*] (major loop, flat minor loops)."""
        sig = stress(xi, temp, exc)
        if xi > branch(temp, sig, a_s, a_f):  # heating pushes xi down to the heating branch
            return consistent(temp, exc, a_s, a_f)
        if xi < branch(temp, sig, m_f, m_s):  # cooling pushes xi up to the cooling branch
            return consistent(temp, exc, m_f, m_s)
        return xi

    def rhs(t: float, temp: float, th: float, om: float, phi: float, xi: float, d: float):
        """Derivatives (T', theta', omega', phi') and the contact force."""
        hconv = h1 + h2 * temp * temp
        d_t = (p_full * d - hconv * surface * (temp - t0c)) / heat_cap
        exc = r_theta * th + r_phi * phi
        f_act = stress(xi, temp, exc) * area_x
        f_pas = pre_pass + k_pass * exc
        if f_pas < 0.0:
            f_pas = 0.0
        t_wires = r_theta * (f_act - f_pas)  # both wires run the same pulleys (eq 5)
        force = t_wires / _interp(lev_t, th)
        dd = math.sqrt(c_e * c_e + c_s * c_s - 2.0 * c_e * c_s * math.cos(phi)) - gap0
        kk = k_pad * (1.0 - creep * (1.0 - math.exp(-t / 8.0))) if creep else k_pad
        d_phi = (force - (kk * dd if phi >= 0.0 else -kk * dd)) / (c_pad * c_e)
        ln = l_rest + arm * th / l_o
        q = t_wires - b_joint * om
        if ln > 1.0:
            q -= arm * f_o * (math.exp(k_pe * (ln - 1.0) / e_o) - 1.0) / fl_den
        if pm_a or pm_c:
            q -= pm_a * (math.exp(pm_b * th) - 1.0) + pm_c * om
        if hc_on and th > hc_angle:
            pen = th - hc_angle
            p15 = pen * math.sqrt(pen)
            tc = hc_k * p15 + hc_c * p15 * om
            if tc > 0.0:
                q -= tc
        if fc:
            q -= fc * math.tanh(om / v_tanh)
        d_om = (q - 0.5 * _interp(dme_t, th) * om * om - _interp(g_t, th)) / _interp(me_t, th)
        return d_t, om, d_om, d_phi, force

    st = {"temperature_c": t0c, "theta_rad": 0.0, "omega_rad_s": 0.0, "phi_rad": 0.0, "xi": 1.0,
          **(state0 or {})}
    temp, th, om, phi, xi = st["temperature_c"], st["theta_rad"], st["omega_rad_s"], st["phi_rad"], st["xi"]
    held = th
    cmd = np.zeros(n)
    out = {k: np.zeros(n) for k in ("t", "duty", "theta_rad", "force_n", "temperature_c", "xi", "phi_rad",
                                    "encoder_rad")}
    lag = delay / dt

    def applied(tt: float, now: int) -> float:
        """The duty the wire sees at time tt inside sample ``now``: the command held over its sample
        (zero-order hold), delay_s late, less the dead time."""
        j = min(math.floor(tt / dt - lag + 1e-9), now)
        if j < 0:
            return 0.0
        d = cmd[j] - dead
        return 0.0 if d < 0.0 else (1.0 if d > 1.0 else d)

    for k in range(n):
        t = k * dt
        xi = martensite(xi, temp, r_theta * th + r_phi * phi)
        if play > 0.0:
            held = min(max(held, th - 0.5 * play), th + 0.5 * play)
        else:
            held = th
        cmd[k] = controller(k, held) if controller is not None else duty[k]
        force = rhs(t, temp, th, om, phi, xi, 0.0)[4]
        out["t"][k], out["duty"][k], out["theta_rad"][k], out["force_n"][k] = t, cmd[k], th, force
        out["temperature_c"][k], out["xi"][k], out["phi_rad"][k], out["encoder_rad"][k] = temp, xi, phi, held
        for j in range(substeps):
            ts = t + j * h
            if j:
                xi = martensite(xi, temp, r_theta * th + r_phi * phi)
                if play > 0.0:
                    held = min(max(held, th - 0.5 * play), th + 0.5 * play)
            d0, d1 = applied(ts, k), applied(ts + h - 1e-12, k)
            # SSP-RK3 (Shu-Osher): u1 = u + h f(u); u2 = 3/4 u + 1/4 (u1 + h f(u1)); u' = 1/3 u + 2/3 (u2 + h f(u2))
            a = rhs(ts, temp, th, om, phi, xi, d0)
            T1, q1, w1, p1 = temp + h * a[0], th + h * a[1], om + h * a[2], phi + h * a[3]
            a = rhs(ts + h, T1, q1, w1, p1, xi, d1)
            T2 = 0.75 * temp + 0.25 * (T1 + h * a[0])
            q2 = 0.75 * th + 0.25 * (q1 + h * a[1])
            w2 = 0.75 * om + 0.25 * (w1 + h * a[2])
            p2 = 0.75 * phi + 0.25 * (p1 + h * a[3])
            a = rhs(ts + 0.5 * h, T2, q2, w2, p2, xi, applied(ts + 0.5 * h, k))
            temp = temp / 3.0 + 2.0 / 3.0 * (T2 + h * a[0])
            th = th / 3.0 + 2.0 / 3.0 * (q2 + h * a[1])
            om = om / 3.0 + 2.0 / 3.0 * (w2 + h * a[2])
            phi = phi / 3.0 + 2.0 / 3.0 * (p2 + h * a[3])
    return out


class _PID:
    """PID on the quantised encoder angle [deg] -> duty 0..1 at 1 kHz: filtered derivative (10 ms),
    conditional-integration anti-windup, a small feed-forward bias for holding a bend."""

    def __init__(self, rng: np.random.Generator, ref: Callable[[float], float], dt: float, lsb_deg: float) -> None:
        self.kp = 0.06 + rng.uniform(0.0, 0.03)  # duty per deg
        self.ki = 0.10 + rng.uniform(0.0, 0.08)  # duty per deg s
        self.kd = 0.004  # duty per deg/s
        self.ref, self.dt, self.lsb = ref, dt, lsb_deg
        self.integ, self.prev, self.dfilt = 0.0, 0.0, 0.0

    def __call__(self, k: int, encoder_rad: float) -> float:
        ang = math.floor(math.degrees(encoder_rad) / self.lsb + 0.5) * self.lsb
        e = self.ref(k * self.dt) - ang
        self.dfilt += ((e - self.prev) / self.dt - self.dfilt) * self.dt / (0.01 + self.dt)
        self.prev = e
        u = 0.2 + self.kp * e + self.ki * self.integ + self.kd * self.dfilt
        if (0.0 < u < 1.0) or u * e < 0.0:
            self.integ += e * self.dt
        return min(max(u, 0.0), 1.0)


def sma_independent_record(effects: dict[str, dict[str, float]], errors: dict[str, float], seed: int,
                           duration_s: float = 20.0, rate_hz: float = 500.0, closed_loop: bool = False, *,
                           start_at_rest: bool = False, sensors: bool = True,
                           duty: np.ndarray | None = None) -> Recording:
    """A record of the SMA exoskeleton from this independent simulator (module docstring).

    ``effects``: hidden effects, library names with this module's laws (``EFFECT_LAWS``);
    ``errors``: relative parameter errors ``supply``, ``h1``, ``muscle_f_o`` and the out-of-library
    ``prestrain`` and ``pad_creep`` (``ERRORS``). Unknown names raise ``ValueError``.
    ``start_at_rest``: start from ambient rest at t = 0 and skip the cut (for cross-checks);
    ``sensors=False``: log the true angle and force (no quantisation, noise or clipping);
    ``duty``: an open-loop duty train at 1 kHz from t = 0 (else a random one; ignored in closed loop).
    With sensors the record is flagged ``rig`` (its force ADC clips at 0 and 1023 counts: the model's
    contact force goes negative, down to about -0.4 N, while the passive wire holds a cooling bend)."""
    _check(effects, errors)
    cfg = _config()
    rng = np.random.default_rng(seed)
    dt = 1e-3
    cut = 0.0 if start_at_rest else float(rng.uniform(6.0, 12.0))
    n = round((cut + duration_s) / dt)
    lsb_deg = 360.0 / cfg["encoder"]["counts_per_rev"]
    if closed_loop:
        res = simulate(effects, errors, n_steps=n, dt=dt, controller=_PID(rng, _reference(rng, cut + duration_s),
                                                                            dt, lsb_deg))
    else:
        train = np.asarray(duty, float)[:n] if duty is not None else _duty_train(rng, n, dt)
        res = simulate(effects, errors, train, dt=dt)
    every = round(1.0 / (rate_hz * dt))
    keep = np.arange(round(cut / dt), res["t"].size, every)
    t = res["t"][keep] - res["t"][keep[0]]
    force = res["force_n"][keep]
    angle = np.degrees(res["encoder_rad"][keep])
    if sensors:
        sg = effects.get("sensor_gain_offset", {})
        per_n = cfg["force_sensor"]["counts_per_n"]
        raw = (1.0 + sg.get("gain_error_fraction", 0.0)) * force + sg.get("offset_counts", 0.0) / per_n
        counts = np.clip(np.round((raw + rng.normal(0.0, 0.03, keep.size)) * per_n
                                  + cfg["force_sensor"]["offset_counts"]), 0, 1023)
        force = (counts - cfg["force_sensor"]["offset_counts"]) / per_n
        angle = np.round(angle / lsb_deg) * lsb_deg
    else:
        angle = np.degrees(res["theta_rad"][keep])
    return Recording(t, {"pwm_duty": res["duty"][keep],
                         "supply_voltage_v": np.full(keep.size, float(cfg["drive"]["supply_voltage_v"])),
                         "theta_mcp_deg": angle, "contact_force_n": force}, rig=sensors)
