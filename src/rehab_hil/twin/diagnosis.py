"""The quick diagnosis of a model mismatch: which single library effect or plant parameter explains
the recent window best (issue 23, item 4; docs/twin.md, "The quick diagnosis").

When the twin's monitor fires (``model_mismatch``), the window since is replayed with the
discrepancy workflow's machinery, cut down to stay cheap beside a 1 kHz loop: the twin's state (or
the workflow's start estimate), every candidate screened from the workflow's regression start, the
best ``REFINE`` refined by a short least squares, ranked by how much each cuts the window's weighted
residual. The likeliest is named when it passes the workflow's rule (``significance.significant``)
without its BIC margin, which a few seconds of smooth residual cannot reach, and cuts the residual by
``MIN_REDUCTION``; a parameter goes before an effect it ties with, as in the workflow. Candidates
include the session parameters a plant does not declare offline (``SESSION_PARAMETERS``) and the
configured effects' magnitudes; the event's words come from the changed quantity (``FAMILY``).
"""

from __future__ import annotations

import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from scipy.optimize import least_squares

from rehab_hil.discrepancy import localise
from rehab_hil.discrepancy.fitting import Objective, Term, effect_term, fit_joint, regression_start
from rehab_hil.discrepancy.initial_state import estimate_initial_state, state_scales
from rehab_hil.discrepancy.parameters import ERROR_PARAM, ParameterTerm, parameter_terms
from rehab_hil.discrepancy.replay import Replay
from rehab_hil.discrepancy.selection import Score, bic, bounded, effective_fraction
from rehab_hil.discrepancy.shooting import choose_mode
from rehab_hil.discrepancy.significance import demanding_channels, score, significant
from rehab_hil.discrepancy.verdict import tied_parameter
from rehab_hil.effects import EFFECTS, EffectParam
from rehab_hil.interchange import CsvError, Recording
from rehab_hil.plants.experiments import FitParameter
from rehab_hil.plants.registry import Plant

__all__ = ["ERROR", "MIN_REDUCTION", "SESSION_PARAMETERS", "Cause", "Diagnosis", "Window", "candidate_terms",
           "changed_window", "diagnose", "rig_channels"]

# a diagnosis parameter's relative error: factor 0.2 .. 6 of the config's value (a stiffness doubling
# or a passive muscle five times as strong inside the bounds, not on them; a TCP heating power halved
# by a sagging supply sat on the old lower bound of -50 %)
ERROR = EffectParam(ERROR_PARAM.name, -0.8, 5.0, ERROR_PARAM.typical)
MIN_REDUCTION = 0.5  # the likeliest cause must cut the window's weighted residual (sum of squares) this much
# candidates refined after the screen (a Coulomb friction's regression start, linearised at "off",
# screened 7th on an SMA window it explained best once refined)
REFINE = 8
START_WINDOW_S = 1.0  # the unmeasured start states are refined on this much of the window
START_DIFF_STEP = 0.3  # their finite-difference step, a share of each state's spread (sees through a count)
# a parameter's screen also tries these relative errors: the SMA is far from linear in its supply
# (the transformation's threshold), and the regression's step of +10 % pointed a supply 8 % low the
# wrong way (refined to -0.4 %, while an actuator dead zone took the first place)
ERROR_GRID = (-0.3, -0.15, -0.07, 0.1, 0.4, 1.0, 3.0)
# an effect and a parameter whose leftover residuals are within this factor are a tie, and the
# parameter is named (the workflow's rule, ``verdict``: a supply 8 % low and a driver dead zone of
# 0.06 are the same thing at one duty level)
TIE_SHARE = 1.25
ALIKE_MAX = 3  # candidates of other quantities that explain the window as well, named after the likeliest
ALSO_SHARE = 0.9  # another candidate of the same family within this share of the best's reduction is named too

# Parameters a session can see change that the plants do not declare for the offline workflow.
SESSION_PARAMETERS: dict[str, tuple[FitParameter, ...]] = {
    "sma_exoskeleton": (
        FitParameter("sma.prestrain", diagram=("sma_active.prestrain",)),  # seed 000 Table 2, eq 14
        FitParameter("contact.stiffness_n_per_m",  # seed 000 eq 18-28, Table 4 (the pad and the contact force)
                     diagram=("pad.stiffness_n_per_m", "contact.stiffness_n_per_m")),
    ),
    "tcp_finger": (
        FitParameter("finger.spring_nm_per_deg",  # seed 001 Table 2: K of every joint
                     diagram=("spring_mcp.stiffness_nm_per_rad", "spring_pip.stiffness_nm_per_rad",
                              "spring_dip.stiffness_nm_per_rad")),
        # the heating power at full duty scales with the supply voltage squared (seed 001 eq 1: P = V^2 / R)
        FitParameter("muscle.max_power_w", inputs=("power_w",)),
    ),
    "finger_extensor": (
        FitParameter("motor.supply_v", inputs=("motor_voltage_v",)),  # seed 002 sec 3.2: the PWM's full scale
    ),
}

# family of each candidate: what physical quantity it changes (the words of the event)
FAMILY: dict[str, str] = {
    "passive_muscle": "passive stiffness", "contact_spring_damper": "passive stiffness",
    "iris.spring_nm_per_rad": "passive stiffness", "muscle.max_isometric_force_n": "passive stiffness",
    "contact.stiffness_n_per_m": "passive stiffness", "finger.spring_nm_per_deg": "passive stiffness",
    "coulomb_friction": "friction", "viscous_friction": "damping", "backlash": "backlash",
    "time_delay": "actuator delay", "actuator_dead_zone": "actuator dead zone", "constant_load": "constant load",
    "sma_hysteresis": "SMA hysteresis", "nonlinear_convection": "cooling",
    "sensor_gain_offset": "force sensor calibration", "sensor_creep_hysteresis": "force sensor creep",
    "drive.supply_voltage_v": "supply voltage", "sma.prestrain": "SMA wire prestrain",
    "motor.supply_v": "supply voltage", "muscle.max_power_w": "supply voltage",
    "sma.h1_w_per_m2_c": "wire cooling", "motor.kt_nm_per_a": "motor torque constant",
    "motor.resistance_ohm": "motor resistance", "motor.rotor_inertia_kg_m2": "inertia",
}
_FALLING = {"supply voltage": "supply sagging", "SMA wire prestrain": "SMA wire losing prestrain"}
_APPEARING = {"friction", "backlash", "actuator dead zone", "constant load"}  # an effect from nothing "appears"


@dataclass(frozen=True)
class Cause:
    """One candidate's single-term fit on the window."""

    name: str  # effect name, or the config key of a parameter (``effects.<i>.params.<p>`` for a configured effect's)
    kind: str  # "effect" or "parameter"
    family: str  # the physical quantity it changes ("passive stiffness", "friction", ...)
    params: dict[str, float]  # fitted values, SI (a parameter: {"error_fraction": relative error})
    relative_change: float | None  # a parameter's relative error; None for an effect from nothing
    reduction: float  # 1 - weighted sum of squares with it / without it, on the window
    significant: bool  # cuts a channel's error by 15 %, more than a rounding of "off", a sensor where it is off
    refined: bool  # refined by least squares (else: the regression start of the screen)
    text: str  # "passive stiffness rising: passive_muscle, +40 %"


@dataclass
class Diagnosis:
    """The candidates ranked by how much each cuts the window's residual, and the event's line."""

    causes: list[Cause]
    likeliest: Cause | None  # None: no single effect explains it
    text: str
    channels: list[str]
    mode: str  # replay: "open" or "shooting"
    baseline_rms: float  # weighted scaled RMS of the residual without any candidate
    cpu_s: float  # CPU time of this call (the calling thread's)
    n_simulations: int
    skipped: list[str] = field(default_factory=list)  # candidates the budget left unscreened


def _family(replay: Replay, name: str) -> str:
    if name.startswith("effects."):  # a configured effect's parameter: the effect's family
        return FAMILY.get(replay.cfg.effects[int(name.split(".")[1])].name, name)
    if name.startswith("sma.convection"):
        return "wire cooling"
    if name.startswith("motor.flux"):
        return "motor magnet"
    return FAMILY.get(name, name)


def _scans(term: Term) -> bool:
    """Does the term's regression start scan a grid (a shape parameter) or several magnitudes?"""
    return sum(1 for p in term.params if p.linear) > 1 or any(not p.linear for p in term.params)


def _configured_effect_terms(replay: Replay) -> list[ParameterTerm]:
    """The config's own ``[[effects]]`` magnitude parameters (non-zero) as relative-error terms, and,
    for an effect with several, all of them scaled together (``effects.<i>.params``: a patient's
    contact that stiffens as a whole, stiffness and damping alike, as spasticity does; a stiffness-only
    term left 1.5x the residual of a supply sag on such a doubling)."""
    out = []
    seen: dict[str, int] = {}
    P = replay.nominal_params()
    d = replay.system.diagram
    for i, spec in enumerate(getattr(replay.cfg, "effects", ()) or ()):
        seen[spec.name] = seen.get(spec.name, 0) + 1
        part = f"effect_{spec.name}" + (f"_{seen[spec.name]}" if seen[spec.name] > 1 else "")
        mags: list[tuple[str, int]] = []
        for p in EFFECTS[spec.name].params:
            if not p.linear or p.off is None:
                continue
            try:
                idx = d.param_index(f"{part}.{p.name}")
            except (KeyError, ValueError):
                continue
            if P[idx] != 0.0:
                mags.append((p.name, idx))
                fp = FitParameter(f"effects.{i}.params.{p.name}", diagram=(f"{part}.{p.name}",),
                                  label=f"effects.{i}.params.{p.name}")
                out.append(ParameterTerm(fp, (idx,), (float(P[idx]),)))
        if len(mags) > 1:
            fp = FitParameter(f"effects.{i}.params", diagram=tuple(f"{part}.{n}" for n, _ in mags))
            out.append(ParameterTerm(fp, tuple(j for _, j in mags), tuple(float(P[j]) for _, j in mags)))
    return out


def _session_terms(replay: Replay) -> list[ParameterTerm]:
    out = []
    P = replay.nominal_params()
    d = replay.system.diagram
    for fp in SESSION_PARAMETERS.get(replay.spec.name, ()):
        try:
            idx = tuple(d.param_index(q) for q in fp.diagram)
        except (KeyError, ValueError):
            continue
        idx += tuple(replay.input_scale_index(u) for u in fp.inputs if u in replay.system.input_names)
        nominal = tuple(float(P[i]) for i in idx)
        if any(v != 0.0 for v in nominal):
            out.append(ParameterTerm(fp, idx, nominal))
    return out


def candidate_terms(replay: Replay) -> list[Term]:
    """Every candidate of the diagnosis: the library effects that attach to the plant, its declared
    fit parameters, the session parameters and the configured effects' magnitudes."""
    # a refinement (a level per direction) needs records of both directions: the set search's, not a window's
    terms = [effect_term(replay, e) for e in replay.candidates if not e.refines]
    params: dict[str, ParameterTerm] = {}
    for p in [*parameter_terms(replay), *_session_terms(replay), *_configured_effect_terms(replay)]:
        params.setdefault(p.name, p)
    terms += [Term(p.name, "parameter", (ERROR,), p.apply) for p in params.values()]
    return terms


def _change_text(term: Term, values: Mapping[str, float], relative: float | None) -> str:
    if relative is not None:
        return f"{100.0 * relative:+.0f} %"
    mags = [p for p in term.params if p.off is not None]
    shown = mags or list(term.params)
    return ", ".join(f"{p.name}={values[p.name]:.3g}" for p in shown)


def _set_start_state(replay: Replay, x0: Any, xd0: Any) -> None:
    s = replay.system
    if x0 is not None:
        x = np.asarray(x0, float)
        if x.shape != s.x0.shape:
            raise ValueError(f"x0 has {x.size} states; the twin's diagram of {replay.spec.name!r} has {s.x0.size} "
                             f"({', '.join(s.diagram.state_names)})")
        replay.x0 = x.copy()
    if xd0 is not None:
        xd = np.asarray(xd0, float)
        if xd.shape != s.xd0.shape:
            raise ValueError(f"xd0 has {xd.size} discrete states; the diagram has {s.xd0.size}")
        replay.xd0 = xd.copy()
    replay.fit_start = 0


def _refine_start(replay: Replay, P: np.ndarray) -> int:
    """A second look at the unmeasured start states (velocity, current, an unmeasured temperature)
    with a coarse finite-difference step: on a window cut while the finger moves, the encoder's
    quantisation made the workflow's nuisance fit (``initial_state``, 5 % steps) stop at its start
    (a Finger Extensor window at -1.66 rad/s kept 0 rad/s and left a 1.1 deg residual the candidates
    then competed to explain). The cause: scipy's ``diff_step`` is relative to the variable, and a
    nuisance offset starting at 0 gets a step of 1e-8, below a count. Here the variable is 1 + the
    offset, so the step is ``START_DIFF_STEP`` of the state's spread. Returns the simulations used."""
    s = replay.system
    K = replay.anchor_gain
    matched = set(np.nonzero(np.any(K != 0.0, axis=1))[0]) if K is not None else set()
    scales, lo, hi = state_scales(replay, P)
    free = [i for i in range(s.x0.size) if i not in matched and hi[i] > lo[i]]
    if not free:
        return 1
    n_win = max(2, min(int(np.searchsorted(replay.t, START_WINDOW_S)), replay.t.size))
    base = replay.x0.copy()
    count = [1]

    def fun(z: np.ndarray) -> np.ndarray:
        count[0] += 1
        x = base.copy()
        x[free] += (z - 1.0) * scales[free]
        r = replay.residual(replay.simulate_from(P, n_win, x, replay.xd0.copy()), slice(0, n_win),
                            weighted=True).ravel()
        return bounded(r)

    zlo = 1.0 + np.minimum((lo[free] - base[free]) / scales[free], -1e-9)
    zhi = 1.0 + np.maximum((hi[free] - base[free]) / scales[free], 1e-9)
    z0 = np.ones(len(free))
    c0 = float(np.mean(fun(z0) ** 2))
    sol = least_squares(fun, z0, bounds=(zlo, zhi), diff_step=START_DIFF_STEP, max_nfev=10 * len(free),
                        xtol=1e-3, ftol=1e-4)
    if float(np.mean(sol.fun**2)) < c0:
        replay.x0 = base.copy()
        replay.x0[free] += (sol.x - 1.0) * scales[free]
    return count[0]


def _build(spec: type[Plant], cfg: Any, rec: Recording, steady_ok: bool) -> Replay:
    """``Replay.build`` on the window. Its check refuses inputs that never change (right offline,
    where the start is estimated from the record); from the twin's state a held input is a step
    response worth as much as any (a duty held at 0.4 while the wire heats from the twin's state: 8
    of the 50 changed 4 s windows of bench/diagnosis.py). Then one input's last sample is moved by
    one floating-point ulp, which passes the check and changes no simulation."""
    try:
        return Replay.build(spec, cfg, rec, "<twin window>", closed_loop=False)
    except CsvError:
        present = [n for n in spec.inputs if n in rec.signals]
        if not steady_ok or not present or any(np.ptp(rec.signals[n]) != 0.0 for n in present):
            raise
        signals = dict(rec.signals)
        u = np.array(signals[present[0]], float)
        u[-1] = np.nextafter(u[-1], np.inf)
        signals[present[0]] = u
        return Replay.build(spec, cfg, Recording(rec.t, signals, rig=rec.rig), "<twin window>", closed_loop=False)


def diagnose(spec: type[Plant], cfg: Any, rec: Recording, x0: np.ndarray | Sequence[float] | None = None,
             xd0: np.ndarray | Sequence[float] | None = None, budget_s: float = 4.0,
             refine: int = REFINE) -> Diagnosis:
    """Rank the single causes that explain the mismatch in ``rec`` (the window since the monitor fired).

    ``x0``/``xd0``: the model state at the window's start in the twin's layout (the ``Replay``
    diagram, ``twin.model.TwinModel.x``/``xd``); without them the workflow's start estimate is used.
    ``budget_s``: CPU seconds (this thread): the screen stops at 60 % of it, and a refinement starts
    only if one more as long as the previous fits in it."""
    t0 = time.thread_time()

    def spent() -> float:
        return time.thread_time() - t0

    try:
        replay = _build(spec, cfg, rec, steady_ok=x0 is not None)
    except CsvError as e:  # too short, or inputs constant with no state given: nothing to tell causes apart
        return Diagnosis([], None, "no cause named: " + str(e).split(": ", 1)[-1], [], "", float("nan"), spent(), 0)
    sims = _start_state_and_mode(replay, x0, xd0)
    window = _Window.of(replay)
    if not window.demanding:  # no channel's residual is beyond the noise
        return Diagnosis([], None, "no cause named: the model fits the window within the noise",
                         list(replay.channels), replay.mode, window.baseline_rms, spent(),
                         sims + window.objective.count + 1)
    screened, skipped = window.screen(candidate_terms(replay), lambda: spent() > 0.6 * budget_s)
    sims += window.objective.count
    causes, refine_sims = window.refine(screened, refine, lambda last_fit_s: spent() + last_fit_s < budget_s)
    _rank(causes)
    likeliest, text = _event(causes)
    return Diagnosis(causes, likeliest, text, list(replay.channels), replay.mode, window.baseline_rms, spent(),
                     sims + refine_sims, skipped)


def _start_state_and_mode(replay: Replay, x0: Any, xd0: Any) -> int:
    """Set the window's start state (the twin's, else the workflow's estimate refined) and the replay
    mode; returns the simulations used."""
    P0 = replay.nominal_params()
    N = replay.t.size
    sims = 0
    estimate_initial_state(replay, P0, N)  # also the anchor gain shooting needs
    if x0 is not None or xd0 is not None:
        _set_start_state(replay, x0, xd0)
    else:
        sims += _refine_start(replay, P0)
    replay.mode = choose_mode(replay, P0, N)[0]
    return sims


# one candidate after the screen: reduction of the window's weighted residual, the term, its start values
Screened = tuple[float, Term, dict[str, float]]


@dataclass
class _Window:
    """The window bound for the candidates' fits: the objective the workflow's fits minimise, its
    value for the nominal model, and the nominal model's score that significance is judged against."""

    replay: Replay
    P0: np.ndarray
    objective: Objective
    r0: np.ndarray  # the nominal model's weighted residual (the objective at P0)
    ss0: float  # its mean square
    nominal: dict[str, np.ndarray]
    hold: slice  # the samples scored: from the end of the start state's memory
    frac: float
    base: Score
    demanding: set[str]  # channels beyond the noise: a sensor effect is named only on one of them

    @classmethod
    def of(cls, replay: Replay) -> _Window:
        N = replay.t.size
        P0 = replay.nominal_params()
        objective = Objective(replay, N, None)
        r0 = objective(P0)
        hold = slice(replay.fit_start, N)
        nominal = replay.simulate(P0)
        r_nom = replay.residual(nominal, hold)
        frac = effective_fraction(r_nom)
        return cls(replay, P0, objective, r0, float(np.mean(r0**2)), nominal, hold, frac,
                   bic(r_nom, 0, frac, replay.fit_weight), demanding_channels(replay, nominal, hold))

    @property
    def baseline_rms(self) -> float:
        return float(np.sqrt(self.ss0))

    def reduction(self, cost: float) -> float:
        """The share of the nominal model's mean-square residual a candidate's ``cost`` removes."""
        return 1.0 - cost / self.ss0 if self.ss0 > 0 else 0.0

    def screen(self, terms: Sequence[Term], over_budget: Callable[[], bool]) -> tuple[list[Screened], list[str]]:
        """Each term's regression start (a parameter's also the ``ERROR_GRID``) scored by one run, best
        first; the cheap terms first (one parameter, no grid), so a budget that runs out skips the scans
        (returned second)."""
        r, hold = self.replay, self.hold
        seeds = localise.delay_seeds(r.t[hold], {c: v[hold] for c, v in r.measured.items()},
                                     {c: v[hold] for c, v in self.nominal.items()}, r.channels, r.kinds)
        screened: list[Screened] = []
        skipped: list[str] = []
        for term in sorted(terms, key=lambda t: (t.kind == "effect" and _scans(t), t.kind == "effect")):
            if over_budget():
                skipped.append(term.name)
                continue
            start = regression_start(term, lambda v, t=term: self.objective(t.apply(self.P0, v)), self.r0, seeds)
            tries = [start] + ([{ERROR.name: g} for g in ERROR_GRID] if term.kind == "parameter" else [])
            cost, start = min(((float(np.mean(self.objective(term.apply(self.P0, v)) ** 2)), v) for v in tries),
                              key=lambda c: c[0])
            screened.append((self.reduction(cost), term, start))
        screened.sort(key=lambda s: -s[0])
        return screened, skipped

    def refine(self, screened: Sequence[Screened], refine: int,
               affordable: Callable[[float], bool]) -> tuple[list[Cause], int]:
        """Every screened candidate as a ``Cause``, the first ``refine`` refined by a short least squares
        while ``affordable`` (one more fit as long as the previous); returns them and the simulations."""
        causes: list[Cause] = []
        sims = 0
        last_fit_s = 0.0
        for k, (red, term, start) in enumerate(screened):
            values, P, refined = start, term.apply(self.P0, start), False
            if k < refine and affordable(last_fit_s):
                t_fit = time.thread_time()
                fit = fit_joint(self.replay, self.P0, [term], [start], self.replay.t.size)[0]
                last_fit_s = time.thread_time() - t_fit
                sims += fit.n_simulations
                red_fit = self.reduction(fit.train_cost)
                if red_fit >= red:
                    values, P, red, refined = fit.params, fit.P, red_fit, True
            sig = False
            if refined:
                sig = self._significant(term, values, P)
                sims += 1
            causes.append(self._cause(term, values, red, sig, refined))
        return causes, sims

    def _significant(self, term: Term, values: Mapping[str, float], P: np.ndarray) -> bool:
        """The workflow's rule (``significance.significant``) without its BIC margin: on a few seconds
        the effective sample count is a handful (module docstring)."""
        sc = score(self.replay, self.replay.simulate(P), self.hold, len(term.params), self.frac)
        return significant(self.replay, term, sc, self.base, self.demanding, lambda: term.relevant(values),
                           bic_margin=False)

    def _cause(self, term: Term, values: Mapping[str, float], reduction: float, significant: bool,
               refined: bool) -> Cause:
        relative = float(values[ERROR.name]) if term.kind == "parameter" else None
        family = _family(self.replay, term.name)
        return Cause(term.name, term.kind, family, dict(values), relative, reduction, significant, refined,
                     _sentence_for(self.replay, term, family, values, relative))


def _rank(causes: list[Cause]) -> None:
    """Significant first, then refined, then by reduction; a significant parameter whose leftover
    residual is within ``TIE_SHARE`` of the best effect's goes first (``verdict.tied_parameter``)."""
    causes.sort(key=lambda c: (not c.significant, not c.refined, -c.reduction))
    if not causes:
        return
    left = 1.0 - causes[0].reduction
    tie = tied_parameter(causes[0], [c for c in causes[1:] if c.significant],
                         lambda c: 1.0 - c.reduction <= TIE_SHARE * left)
    if tie is not None:
        causes.remove(tie)
        causes.insert(0, tie)


def _event(causes: Sequence[Cause]) -> tuple[Cause | None, str]:
    """The likeliest cause (significant and cutting ``MIN_REDUCTION``) and the event's line."""
    best = causes[0] if causes else None
    likeliest = best if best is not None and best.significant and best.reduction >= MIN_REDUCTION else None
    if likeliest is not None:
        also = [c.name for c in causes[1:] if c.family == likeliest.family and c.refined
                and c.reduction >= ALSO_SHARE * likeliest.reduction]
        # other quantities that explain the window as well: a short window (a session that ended on the
        # change) can leave a weaker motor, a hotter winding and a new friction exactly alike
        alike = [c.name for c in causes[1:] if c.family != likeliest.family and c.significant and c.refined
                 and 1.0 - c.reduction <= TIE_SHARE * (1.0 - likeliest.reduction)][:ALIKE_MAX]
        text = likeliest.text + (f" (also explained by {', '.join(also)})" if also else "") \
            + (f"; as well explained by {', '.join(alike)}" if alike else "")
    elif best is not None:
        text = (f"no single effect explains it (best: {best.name}, cuts the residual by "
                f"{100.0 * max(best.reduction, 0.0):.0f} %)")
    else:
        text = "no single effect explains it (no candidate tested within the budget)"
    return likeliest, text


def _sentence_for(replay: Replay, term: Term, family: str, values: Mapping[str, float],
                  relative: float | None) -> str:
    """The event line of one candidate; a configured effect's parameter is named with its effect."""
    if relative is not None:
        head = f"{family} rising" if relative >= 0 else _FALLING.get(family, f"{family} falling")
    else:
        head = f"{family} appearing" if family in _APPEARING else f"{family} rising"
    name = term.name
    if name.startswith("effects."):
        i = int(name.split(".")[1])
        effect = replay.cfg.effects[i].name
        name = (f"{effect} as a whole ({name})" if name.endswith(".params")
                else f"{effect}.{name.split('.')[-1]} ({name})")
    return f"{head}: {name}, {_change_text(term, values, relative)}"


@dataclass
class Window:
    """A session window with a known change (tests, ``bench/diagnosis.py``): the recording on the
    rig's signals, and the model state at its start as the twin would hold it."""

    recording: Recording
    x0: np.ndarray
    xd0: np.ndarray


def rig_channels(spec: type[Plant], cfg: Any) -> set[str]:
    """The columns a rig records of this plant: its inputs and the outputs an encoder or an ADC reads."""
    ports = spec.ports(cfg)
    outs = {m.signal for m in ports.measured if m.sensor in ("encoder", "adc") and m.signal in spec.outputs}
    return set(spec.inputs) | set(spec.optional_inputs) | outs


def changed_window(spec: type[Plant], cfg: Any, *, effects: Mapping[str, Mapping[str, float]] | None = None,
                   config: Any = None, input_scale: Mapping[str, float] | None = None, change_s: float = 4.0,
                   window_s: float = 4.0, rate_hz: float = 800.0, seed: int = 0, mismatch: bool = True) -> Window:
    """A window of a session in which the plant changes at ``change_s``: before it the model of
    ``cfg``, from it on the same model with ``effects`` switched on, the parameters of ``config``
    (the same plant with some values changed, e.g. ``cfg.model_copy(update=...)``), and the inputs
    scaled by ``input_scale`` behind the recorded columns (a supply that sags while the rig logs the
    config's constant). Drive, sensor noise, logger rate and the small unrelated mismatch are the
    plant's ``excitation``, as ``discrepancy.synthetic.hidden_effect_recording`` makes them. The
    window is ``[change_s, change_s + window_s)`` on the rig's columns (``rig_channels``)."""
    plan = spec.excitation
    if plan is None:
        raise ValueError(f"plant {spec.name!r} declares no excitation for synthetic records")
    rng = np.random.default_rng(seed)
    step_s = spec.step(cfg)[0]
    n = round((change_s + window_s) / step_s) + 2
    t = np.arange(n) * step_s
    u = plan.inputs(t, rng)
    signals = {**u, **{c: np.zeros(n) for c in spec.outputs}}
    replay = Replay.build(spec, cfg, Recording(t, signals), "<window>", closed_loop=False)
    before = replay.nominal_params()
    if mismatch:
        name, factor = plan.mismatch
        before[replay.system.diagram.param_index(name)] *= factor
    after = before.copy()
    if config is not None:
        changed = Replay.build(spec, config, Recording(t, signals), "<window>", closed_loop=False).nominal_params()
        npar = replay.n_diagram_params
        if changed.size != before.size:
            raise ValueError("config changes the diagram's structure; give parameter values only")
        moved = changed[:npar] != replay.nominal_params()[:npar]
        after[:npar][moved] = changed[:npar][moved]
    after = replay.with_effects(after, effects or {})
    for name, factor in (input_scale or {}).items():
        after[replay.input_scale_index(name)] = factor
    k = round(change_s / step_s)
    x, xd = replay.system.x0.copy(), replay.system.xd0.copy()
    replay.run(before, 0, k, x, xd)
    x_at, xd_at = x.copy(), xd.copy()
    Y = replay.run(after, k, n - k, x, xd)
    tm = np.arange(0.0, window_s - step_s, 1.0 / rate_hz)
    idx = np.minimum(np.floor(tm / step_s + 1e-9).astype(np.int64), n - k - 1)
    keep = rig_channels(spec, cfg)
    out = {name: u[name][k + idx] for name in u if name in keep}
    for j, c in enumerate(replay.channels):
        if c in keep:
            sd = plan.noise.get(c, 0.0)
            out[c] = Y[idx, j] + (rng.normal(0.0, sd, tm.size) if sd > 0 else 0.0)
    return Window(Recording(tm, out), x_at, xd_at)
