"""The discrepancy workflow: start state, replay mode, fit every candidate, select, refit, repeat.

1. The start state comes from the data (``initial_state``); the replay is open loop unless drift
   dominates (``shooting``).
2. Candidates are the library effects that attach to the plant's ports and the plant's declared
   nominal parameters (``parameters``). The first ``1 - holdout_fraction`` of the record fits;
   the rest is held out and scores them (``selection``). The best significant one is chosen (a
   parameter before an effect when the two are near-aliases, ``verdict``), then every chosen term
   is refitted jointly (from the second round the best ``JOINT_CANDIDATES`` candidates are scored
   after a joint refit with the chosen terms, so an effect chosen first cannot hide the next by
   having absorbed part of it), and the search repeats while a candidate is significant (at most
   ``max_effects`` rounds). After each choice the start state is re-estimated and the replay mode
   chosen again, and the joint refit starts from that state. A term must be relevant
   (``Term.relevant``: more than a rounding of "off"); one the joint refit switches off is dropped.
3. A channel whose final held-out error the noise cannot account for is reported as an
   unexplained residual, with where it sits (``verdict``).
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from rehab_hil.discrepancy import localise
from rehab_hil.discrepancy.fitting import Fit, Term, effect_term, fit_joint, fit_term, parameter_term
from rehab_hil.discrepancy.identify import identify_jointly
from rehab_hil.discrepancy.initial_state import estimate_initial_state
from rehab_hil.discrepancy.parameters import parameter_terms
from rehab_hil.discrepancy.replay import Replay
from rehab_hil.discrepancy.result import Alias, Candidate, Result, Round
from rehab_hil.discrepancy.selection import (
    MIN_IMPROVEMENT,
    RESOLUTION_FLOOR,
    bic,
    effective_fraction,
    improvement,
    is_significant,
)
from rehab_hil.discrepancy.shooting import choose_mode
from rehab_hil.discrepancy.verdict import ALIAS_DELTA_BIC, experiment, is_alias, unexplained_channels
from rehab_hil.effects import EFFECTS
from rehab_hil.interchange import Recording
from rehab_hil.plants import get_plant

__all__ = ["JOINT_CANDIDATES", "Candidate", "Options", "Progress", "Result", "Round", "find_missing_effects"]

JOINT_CANDIDATES = 3  # from the second round, the best few candidates are refitted with the chosen terms


class Progress:
    """Progress hooks (no-op here; the CLI shows a rich progress bar)."""

    def start(self, label: str, total: int | None = None) -> None:
        """A new stage begins."""

    def advance(self) -> None:
        """One simulation done."""


@dataclass(frozen=True)
class Options:
    holdout_fraction: float = 0.4  # final share of the record kept out of the fit
    fit_max_s: float = 20.0  # longer records fit on their first fit_max_s only (the rest is held out)
    max_effects: int = 3  # rounds of the search (effects and parameters chosen)
    mode: str = "auto"  # "auto", "open" or "shooting" (docs/discrepancy.md)
    parameters: bool = True  # the plant's declared nominal parameters are candidates too
    joint: bool = True  # finally every declared parameter and chosen term fitted together (``identify``)
    closed_loop: bool = True  # replay a record from its reference under the config's [recorded_controller]


def _score(replay: Replay, sim: dict[str, np.ndarray], hold: slice, n_params: int, frac: float):
    return bic(replay.residual(sim, hold), n_params, frac, replay.fit_weight)


def _relevant(replay: Replay, term: Term, fit: Fit, sim: dict[str, np.ndarray], hold: slice, base) -> bool:
    """Is a fitted term more than a rounding of "off"? By its magnitude (``Term.relevant``) or, for
    an effect, by what it does: switched off, some channel's held-out output moves by at least
    ``MIN_IMPROVEMENT`` of that channel's current error (and more than the resolution floor). A
    passive muscle fitted as a small scale with a steep shape (0.0005 N m x e^(6.5 q)) gives the
    torque of the hidden 0.01 N m x e^(2 q) over the motion, though its scale alone looks like "off"."""
    if term.relevant(fit.params):
        return True
    if term.kind != "effect":
        return False
    off = replay.simulate(term.apply(fit.P, term.off()))
    moved = np.sqrt(np.mean((replay.residual(sim, hold) - replay.residual(off, hold)) ** 2, axis=1))
    return any(m >= MIN_IMPROVEMENT * b and m > RESOLUTION_FLOOR for m, b in zip(moved, base.channel_rms, strict=True))


def _demanding(replay: Replay, current: dict[str, np.ndarray], hold: slice) -> set[str]:
    """Channels whose held-out error under the current model the noise cannot account for."""
    rms = {c: float(np.sqrt(np.mean((current[c][hold] - replay.measured[c][hold]) ** 2))) for c in replay.channels}
    return set(unexplained_channels(replay.channels, {c: replay.measured[c][hold] for c in replay.channels}, rms))


def _sensor_demanded(replay: Replay, term: Term, demanding: set[str]) -> bool:
    """A sensor effect on a measured channel is named only when that channel itself demands it: its
    held-out error is beyond its noise and 2 % of its spread under the current model. Otherwise a
    sensor gain soaks up what a physical effect left on the force (an SMA record with a passive
    stiffness only had a spurious Flexiforce gain of -13 % named beside it). A sensor on a recorded
    input (the FE torque sensor) shows in other channels and is not restricted."""
    if term.kind != "effect" or EFFECTS[term.name].needs != "adc":
        return True
    port = EFFECTS[term.name].port(replay.ports)
    signal = getattr(port, "signal", None)
    return signal not in replay.channels or signal in demanding


def find_missing_effects(cfg: Any, rec: Recording, data_path: str | Path = "<data>",
                         progress: Progress | None = None, options: Options | None = None) -> Result:
    """Run the workflow on a loaded config and recording; see the module docstring."""
    t_start = time.perf_counter()
    progress = progress or Progress()
    options = options or Options()
    spec = get_plant(cfg.plant)
    progress.start("replay nominal model", 1)
    replay = Replay.build(spec, cfg, rec, data_path, closed_loop=options.closed_loop)
    N = replay.t.size
    n_train = max(2, min(round((1.0 - options.holdout_fraction) * N),
                         int(np.searchsorted(replay.t, options.fit_max_s))))
    hold = slice(n_train, N)
    P0 = replay.nominal_params()
    initial = estimate_initial_state(replay, P0, n_train)
    mode, open_rms, shoot_rms = choose_mode(replay, P0, n_train)
    if replay.loop:  # the replayed controller keeps the model on the reference: nothing drifts to re-anchor
        mode = "open"
    replay.mode = mode if options.mode == "auto" else options.mode
    nominal = replay.simulate(P0)
    progress.advance()
    kinds = {c: replay.ports.measured_kind(c) or "" for c in replay.channels}
    lag = localise.signatures(replay.t, replay.measured, nominal, replay.channels[:1], kinds)[replay.channels[0]]
    seeds = {"delay_s": [lag["lag_s"]]} if lag["lag_s"] > 0 else {}
    terms: list[Term] = [effect_term(replay, e) for e in replay.candidates]
    if options.parameters:
        terms += [parameter_term(p) for p in parameter_terms(replay)]
    descriptions = {e.name: e.description for e in EFFECTS.values()}
    P, current, n_params = P0, nominal, 0
    chosen_terms: list[Term] = []
    chosen: list[Fit] = []
    rounds: list[Round] = []
    aliases: list[Alias] = []
    dropped: set[str] = set()
    for _ in range(options.max_effects):
        r_cur = replay.residual(current, hold)
        frac = effective_fraction(r_cur)
        base = bic(r_cur, n_params, frac, replay.fit_weight)
        demanding = _demanding(replay, current, hold)
        cands: list[Candidate] = []
        joint: dict[str, list[Fit]] = {}  # candidate -> its joint fit with the chosen terms
        for term in [t for t in terms if t.name not in {c.name for c in chosen_terms} | dropped]:
            progress.start(f"round {len(rounds) + 1}: fitting {term.name}", None)
            fit = fit_term(replay, P, term, n_train, progress.advance, seeds)
            sim = replay.simulate(fit.P)
            sc = _score(replay, sim, hold, n_params + len(term.params), frac)
            sig = is_significant(sc, base) and _relevant(replay, term, fit, sim, hold, base) \
                and _sensor_demanded(replay, term, demanding)
            cands.append(Candidate(fit, sc, sc.bic - base.bic, improvement(sc, base), sig, sim))
        if chosen_terms:  # the best few again, refitted jointly with the chosen terms
            cands.sort(key=lambda c: c.score.bic)
            for i, c in enumerate(cands[:JOINT_CANDIDATES]):
                term = next(t for t in terms if t.name == c.fit.effect)
                progress.start(f"round {len(rounds) + 1}: {term.name} jointly with the chosen", None)
                fits = fit_joint(replay, P0, [*chosen_terms, term], [*(f.params for f in chosen), c.fit.params],
                                 n_train, progress.advance)
                sim = replay.simulate(fits[-1].P)
                sc = _score(replay, sim, hold, n_params + len(term.params), frac)
                if sc.bic < c.score.bic:
                    fit = fits[-1]
                    fit.start = c.fit.start
                    sig = is_significant(sc, base) and _relevant(replay, term, fit, sim, hold, base) \
                        and _sensor_demanded(replay, term, demanding)
                    cands[i] = Candidate(fit, sc, sc.bic - base.bic, improvement(sc, base), sig, sim)
                    joint[fit.effect] = fits
        cands.sort(key=lambda c: (not c.significant, c.score.bic))  # the best significant one first
        pick = cands[0] if cands and cands[0].significant else None
        if pick is not None:
            j = int(np.argmax(np.array(base.channel_rms) - np.array(pick.score.channel_rms)))
            near = [c for c in cands[1:] if c.significant
                    and is_alias(pick.score.bic, c.score.bic, pick.score.channel_rms[j], c.score.channel_rms[j],
                                 pick.fit.train_cost, c.fit.train_cost)]
            param = next((c for c in near if c.fit.kind == "parameter"
                          and abs(c.score.bic - pick.score.bic) < ALIAS_DELTA_BIC), None)
            if pick.fit.kind == "effect" and param is not None:  # a known parameter before new structure
                pick, near = param, [pick, *[c for c in near if c is not param]]
            for c in near:
                split = not is_alias(pick.score.bic, c.score.bic, pick.score.channel_rms[j], c.score.channel_rms[j])
                aliases.append(Alias(len(rounds) + 1, pick.fit.effect, c.fit.effect, c.score.bic - pick.score.bic,
                                     experiment(pick.fit.effect, c.fit.effect, descriptions), split))
        rounds.append(Round(base, cands, pick.fit.effect if pick else None))
        if pick is None:
            break
        chosen_terms.append(next(t for t in terms if t.name == pick.fit.effect))
        chosen = joint.get(pick.fit.effect) or [*chosen, pick.fit]
        initial = estimate_initial_state(replay, chosen[-1].P, n_train)  # the start under the augmented model
        if options.mode == "auto" and not replay.loop:  # drift may dominate once the largest discrepancy is explained
            replay.mode = choose_mode(replay, chosen[-1].P, n_train)[0]
        # every chosen term is refitted jointly, from the new start state: the terms were fitted from
        # the previous one (the nominal model's, in the first round: a supply 8 % low makes it estimate
        # a cold wire), and the next round must not see a residual the chosen terms would explain
        progress.start(f"round {len(rounds)}: joint refit of the chosen terms from the new start state", None)
        chosen = fit_joint(replay, P0, chosen_terms, [f.params for f in chosen], n_train, progress.advance)
        P = chosen[-1].P
        current = replay.simulate(P)
        now = _score(replay, current, hold, 0, frac)
        keep = [i for i, (t, f) in enumerate(zip(chosen_terms, chosen, strict=True))
                if _relevant(replay, t, f, current, hold, now)]
        if len(keep) < len(chosen):  # the joint refit switched a term off: it is not part of the story
            dropped.update(chosen_terms[i].name for i in range(len(chosen)) if i not in keep)
            chosen_terms, chosen = [chosen_terms[i] for i in keep], [chosen[i] for i in keep]
            P = P0
            for t, f in zip(chosen_terms, chosen, strict=True):
                P = t.apply(P, f.params)
            for f in chosen:
                f.P = P
            initial = estimate_initial_state(replay, P, n_train)
            current = replay.simulate(P)
        n_params = sum(len(t.params) for t in chosen_terms)
    joint = None
    if options.joint and options.parameters:
        progress.start("joint identification of every parameter", None)
        joint = identify_jointly(replay, P0, chosen_terms, chosen, n_train, progress.advance)
    for rd in rounds:
        for c in rd.candidates:
            c.sim = None
    replay.drop_cache()
    split_s = float(replay.t[n_train]) if n_train < N else float(replay.t[-1])
    hm = replay.t >= split_s
    rms = {c: float(np.sqrt(np.mean((current[c][hm] - replay.measured[c][hm]) ** 2))) for c in replay.channels}
    unexplained = unexplained_channels(replay.channels, {c: replay.measured[c] for c in replay.channels}, rms)
    where: dict[str, Any] = {}
    if unexplained:
        r = replay.residual(current)
        combined = np.sqrt(np.mean(r**2, axis=0))
        win = max(localise.time_windows(replay.t, combined), key=lambda w: w["rms"])
        regs = [g for g in localise.regions(replay.t, replay.measured, r, replay.channels, kinds)
                if g["ratio"] == g["ratio"]]
        top = max(regs, key=lambda g: float(g["ratio"])) if regs else {"region": "everywhere"}  # type: ignore[arg-type]
        where = {"window_start_s": win["start_s"], "window_end_s": win["end_s"], "region": top["region"]}
    return Result(spec.name, replay.channels, kinds, replay.t, replay.measured, nominal, current, chosen, rounds,
                  split_s, dict(zip(replay.channels, replay.scale.tolist(), strict=True)),
                  time.perf_counter() - t_start, {"replay": replay, "P": P}, initial, replay.mode,
                  {"open_rms": open_rms, "shooting_rms": shoot_rms}, aliases, unexplained, where, joint=joint)
