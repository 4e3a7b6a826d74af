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
3. The chosen terms are judged on held-out data (``judge``): the validation records when given,
   else the record's held-out part; a term that makes them worse than its given value is rejected
   (said in the conclusion, not a finding, its given value kept) and the rest refitted.
4. A channel whose final held-out error the noise cannot account for is reported as an
   unexplained residual, with where it sits (``verdict``).
"""

from __future__ import annotations

import time
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from rehab_hil.discrepancy import localise
from rehab_hil.discrepancy.bounds import at_bound
from rehab_hil.discrepancy.candidates import candidate_terms
from rehab_hil.discrepancy.experiments import lacking, mend_suggestions
from rehab_hil.discrepancy.fitting import Fit, Term, fit_joint, fit_term
from rehab_hil.discrepancy.identify import identify_jointly
from rehab_hil.discrepancy.initial_state import InitialState, estimate_initial_state
from rehab_hil.discrepancy.judge import Judgement, judge_findings
from rehab_hil.discrepancy.records import GAP_MEASURE, gap
from rehab_hil.discrepancy.replay import Replay
from rehab_hil.discrepancy.result import Alias, Candidate, Result, Round
from rehab_hil.discrepancy.selection import Score, bic, effective_fraction, improvement
from rehab_hil.discrepancy.shooting import choose_mode
from rehab_hil.discrepancy.significance import demanding_channels, relevant, score, significant
from rehab_hil.discrepancy.verdict import ALIAS_DELTA_BIC, experiment, is_alias, tied_parameter, unexplained
from rehab_hil.effects import EFFECTS, nested
from rehab_hil.interchange import Recording
from rehab_hil.plants import get_plant

__all__ = ["JOINT_CANDIDATES", "Candidate", "Options", "Progress", "Result", "Round", "Search", "candidate_terms",
           "find_missing_effects", "unexplained"]

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
    # the record's start: "estimate" (the API's default: every held-out benchmark result unchanged), "rest", or
    # "auto" (the CLI's default: at rest when no channel moves at first and a fitted velocity would show)
    start: str = "estimate"
    # "auto": effects chosen as a set (``subsets``) when several records are given, the rounds of
    # ``Search`` on one record; "sets" or "rounds" forces one
    search: str = "auto"


@dataclass(frozen=True)
class Baseline:
    """The current model at the start of a round: what every candidate of the round is judged against."""

    score: Score  # held-out score
    frac: float  # effective share of independent samples in its held-out residual
    demanding: set[str]  # channels whose error the noise cannot account for


@dataclass
class Search:
    """The rounds of the search on one replay (module docstring, step 2).

    Each round scores every open term fitted alone, rescores the best few jointly with the chosen
    terms, picks the best significant one (a parameter before an effect it ties with; near-aliases
    recorded), accepts it (new start state, replay mode, joint refit of every chosen term) and prunes
    the chosen terms that refit switched off."""

    replay: Replay
    terms: list[Term]
    n_train: int
    P0: np.ndarray
    current: dict[str, np.ndarray]  # outputs of the current model (the nominal one to begin with)
    initial: InitialState
    progress: Progress
    seeds: dict[str, list[float]]  # extra starts of shape parameters (``localise.delay_seeds``)
    remode: bool  # choose the replay mode again after each choice
    P: np.ndarray = field(init=False)  # the current model's parameters
    hold: slice = field(init=False)  # the held-out samples
    n_params: int = 0
    chosen_terms: list[Term] = field(default_factory=list)
    chosen: list[Fit] = field(default_factory=list)
    rounds: list[Round] = field(default_factory=list)
    aliases: list[Alias] = field(default_factory=list)
    dropped: set[str] = field(default_factory=set)

    def __post_init__(self) -> None:
        self.P = self.P0
        self.hold = slice(self.n_train, self.replay.t.size)

    def run(self, max_rounds: int) -> None:
        """Rounds until none names a term, at most ``max_rounds``."""
        for _ in range(max_rounds):
            if not self.round():
                break

    def round(self) -> bool:
        """One round; False when no candidate is significant (the search is over)."""
        baseline = self._baseline()
        chosen = {t.name for t in self.chosen_terms}
        cands = [self._fit_alone(t, baseline) for t in self.terms if t.name not in chosen | self.dropped]
        joint = self._rescore_jointly(cands, baseline) if self.chosen_terms else {}
        cands.sort(key=lambda c: (not c.significant, c.score.bic))  # the best significant one first
        pick = self._pick(cands, baseline.score)
        self.rounds.append(Round(baseline.score, cands, pick.fit.effect if pick else None))
        if pick is None:
            return False
        self._accept(pick, joint.get(pick.fit.effect))
        self._prune(baseline.frac)
        self.n_params = sum(len(t.params) for t in self.chosen_terms)
        return True

    def forget_simulations(self) -> None:
        """Drop the candidates' full-record outputs and the replay's cache (the result keeps neither)."""
        for rd in self.rounds:
            for c in rd.candidates:
                c.sim = None
        self.replay.drop_cache()

    def _term(self, name: str) -> Term:
        return next(t for t in self.terms if t.name == name)

    def _baseline(self) -> Baseline:
        r_cur = self.replay.residual(self.current, self.hold)
        frac = effective_fraction(r_cur)
        return Baseline(bic(r_cur, self.n_params, frac, self.replay.fit_weight), frac,
                        demanding_channels(self.replay, self.current, self.hold))

    def _candidate(self, term: Term, fit: Fit, sim: dict[str, np.ndarray], sc: Score, baseline: Baseline) -> Candidate:
        """A fitted term judged against the round's baseline (``significance.significant``)."""
        base = baseline.score
        sig = significant(self.replay, term, sc, base, baseline.demanding,
                          lambda: relevant(self.replay, term, fit, sim, self.hold, base))
        return Candidate(fit, sc, sc.bic - base.bic, improvement(sc, base), sig, sim)

    def _fit_alone(self, term: Term, baseline: Baseline) -> Candidate:
        """``term`` fitted on its own on the current model."""
        self.progress.start(f"round {len(self.rounds) + 1}: fitting {term.name}", None)
        fit = fit_term(self.replay, self.P, term, self.n_train, self.progress.advance, self.seeds)
        sim = self.replay.simulate(fit.P)
        sc = score(self.replay, sim, self.hold, self.n_params + len(term.params), baseline.frac)
        return self._candidate(term, fit, sim, sc, baseline)

    def _rescore_jointly(self, cands: list[Candidate], baseline: Baseline) -> dict[str, list[Fit]]:
        """The best ``JOINT_CANDIDATES`` refitted jointly with the chosen terms, replaced where that scores
        better (an effect chosen first cannot hide the next by having absorbed part of it); returns
        candidate -> its joint fit."""
        joint: dict[str, list[Fit]] = {}
        cands.sort(key=lambda c: c.score.bic)
        for i, c in enumerate(cands[:JOINT_CANDIDATES]):
            term = self._term(c.fit.effect)
            self.progress.start(f"round {len(self.rounds) + 1}: {term.name} jointly with the chosen", None)
            fits = fit_joint(self.replay, self.P0, [*self.chosen_terms, term],
                             [*(f.params for f in self.chosen), c.fit.params], self.n_train, self.progress.advance)
            sim = self.replay.simulate(fits[-1].P)
            sc = score(self.replay, sim, self.hold, self.n_params + len(term.params), baseline.frac)
            if sc.bic < c.score.bic:
                fits[-1].start = c.fit.start
                cands[i] = self._candidate(term, fits[-1], sim, sc, baseline)
                joint[fits[-1].effect] = fits
        return joint

    def _pick(self, cands: list[Candidate], base: Score) -> Candidate | None:
        """The first of the ranked candidates if significant, or a parameter it ties with
        (``verdict.tied_parameter``); its near-aliases are recorded in ``aliases``."""
        if not cands or not cands[0].significant:
            return None
        pick = cands[0]
        j = int(np.argmax(np.array(base.channel_rms) - np.array(pick.score.channel_rms)))
        near = [c for c in cands[1:] if c.significant
                and is_alias(pick.score.bic, c.score.bic, pick.score.channel_rms[j], c.score.channel_rms[j],
                             pick.fit.train_cost, c.fit.train_cost)]
        param = tied_parameter(pick, near, lambda c: abs(c.score.bic - pick.score.bic) < ALIAS_DELTA_BIC)
        if param is not None:
            pick, near = param, [pick, *[c for c in near if c is not param]]
        simpler = next((c for c in near if EFFECTS.get(pick.fit.effect) and EFFECTS[pick.fit.effect].refines
                        == c.fit.effect), None)
        if simpler is not None:  # a refinement that explains no better than what it refines: the simpler one
            pick, near = simpler, [pick, *[c for c in near if c is not simpler]]
        near = [c for c in near if not nested(pick.fit.effect, c.fit.effect)]  # nested models, not aliases
        descriptions = {e.name: e.description for e in EFFECTS.values()}
        for c in near:
            split = not is_alias(pick.score.bic, c.score.bic, pick.score.channel_rms[j], c.score.channel_rms[j])
            self.aliases.append(Alias(len(self.rounds) + 1, pick.fit.effect, c.fit.effect,
                                      c.score.bic - pick.score.bic,
                                      experiment(pick.fit.effect, c.fit.effect, descriptions), split))
        return pick

    def _accept(self, pick: Candidate, joint_fits: list[Fit] | None) -> None:
        """Add the pick to the chosen terms and refit them all jointly from the new start state."""
        self.chosen_terms.append(self._term(pick.fit.effect))
        chosen = joint_fits or [*self.chosen, pick.fit]
        # the start under the augmented model
        self.initial = estimate_initial_state(self.replay, chosen[-1].P, self.n_train)
        if self.remode:  # drift may dominate once the largest discrepancy is explained
            self.replay.mode = choose_mode(self.replay, chosen[-1].P, self.n_train)[0]
        # every chosen term is refitted jointly, from the new start state: the terms were fitted from
        # the previous one (the nominal model's, in the first round: a supply 8 % low makes it estimate
        # a cold wire), and the next round must not see a residual the chosen terms would explain
        self.progress.start(f"round {len(self.rounds)}: joint refit of the chosen terms from the new start state",
                            None)
        self.chosen = fit_joint(self.replay, self.P0, self.chosen_terms, [f.params for f in chosen], self.n_train,
                                self.progress.advance)
        self.P = self.chosen[-1].P
        self.current = self.replay.simulate(self.P)

    def _prune(self, frac: float) -> None:
        """Drop the chosen terms the joint refit switched off: they are not part of the story."""
        now = score(self.replay, self.current, self.hold, 0, frac)
        keep = [i for i, (t, f) in enumerate(zip(self.chosen_terms, self.chosen, strict=True))
                if relevant(self.replay, t, f, self.current, self.hold, now)]
        if len(keep) == len(self.chosen):
            return
        self.dropped.update(self.chosen_terms[i].name for i in range(len(self.chosen)) if i not in keep)
        self.chosen_terms, self.chosen = [self.chosen_terms[i] for i in keep], [self.chosen[i] for i in keep]
        P = self.P0
        for t, f in zip(self.chosen_terms, self.chosen, strict=True):
            P = t.apply(P, f.params)
        for f in self.chosen:
            f.P = P
        self.P = P
        self.initial = estimate_initial_state(self.replay, P, self.n_train)
        self.current = self.replay.simulate(P)


def find_missing_effects(cfg: Any, rec: Recording | Sequence[Recording], data_path: Any = "<data>",
                         progress: Progress | None = None, options: Options | None = None,
                         validation: Sequence[tuple[Recording, str | Path]] = ()) -> Result:
    """Run the workflow on a loaded config and recording (or several records, each with its path in
    ``data_path``: ``set_workflow``); see the module docstring. ``validation``: (recording, path) pairs
    of other records of the plant, on which the chosen terms are judged (``judge``; without any, on the
    records' held-out parts). The result's ``gaps`` give each record's RMSE before and after in one
    measure (``records.GAP_MEASURE``)."""
    progress = progress or Progress()
    options = options or Options()
    recs = [rec] if isinstance(rec, Recording) else list(rec)
    paths = [data_path] if isinstance(rec, Recording) else list(data_path)
    if options.search == "sets" or (options.search == "auto" and len(recs) > 1):
        from rehab_hil.discrepancy.set_workflow import find_in_records

        return find_in_records(cfg, recs, paths, progress, options, validation)
    res = _one_record(cfg, recs[0], paths[0], progress, options, validation)
    progress.start("the gap over the whole record", None)
    replay = res.extras["replay"]
    x0, xd0 = replay.x0, replay.xd0
    res.gaps = {"measure": GAP_MEASURE, "records": [{"data": str(paths[0]),
                                                     "nominal": gap(replay, replay.nominal_params()),
                                                     "augmented": gap(replay, res.extras["P"])}]}
    replay.x0, replay.xd0 = x0, xd0
    res.bounds = at_bound([], [], res.joint)
    res.lacking = lacking(replay)
    mend_suggestions(res.aliases, replay)
    return res


def _one_record(cfg: Any, rec: Recording, data_path: str | Path, progress: Progress, options: Options,
                validation: Sequence[tuple[Recording, str | Path]]) -> Result:
    """The rounds of ``Search`` on one record, their terms judged on held-out data (``judge``)."""
    t_start = time.perf_counter()
    spec = get_plant(cfg.plant)
    progress.start("replay nominal model", 1)
    replay = Replay.build(spec, cfg, rec, data_path, closed_loop=options.closed_loop)
    replay.start = options.start
    N = replay.t.size
    n_train = max(2, min(round((1.0 - options.holdout_fraction) * N),
                         int(np.searchsorted(replay.t, options.fit_max_s))))
    P0 = replay.nominal_params()
    initial = estimate_initial_state(replay, P0, n_train)
    mode, open_rms, shoot_rms = choose_mode(replay, P0, n_train)
    if replay.loop:  # the replayed controller keeps the model on the reference: nothing drifts to re-anchor
        mode = "open"
    replay.mode = mode if options.mode == "auto" else options.mode
    nominal = replay.simulate(P0)
    progress.advance()
    kinds = replay.kinds
    search = Search(replay, candidate_terms(replay, options), n_train, P0, nominal, initial, progress,
                    localise.delay_seeds(replay.t, replay.measured, nominal, replay.channels, kinds),
                    remode=options.mode == "auto" and not replay.loop)
    search.run(options.max_effects)
    judgement = _judge(search, cfg, validation)
    joint = None
    if options.joint and options.parameters:
        progress.start("joint identification of every parameter", None)
        joint = identify_jointly(replay, P0, search.chosen_terms, search.chosen, n_train, progress.advance)
    search.forget_simulations()
    split_s = float(replay.t[n_train]) if n_train < N else float(replay.t[-1])
    unexpl, where = unexplained(replay, search.current, split_s, kinds)
    return Result(spec.name, replay.channels, kinds, replay.t, replay.measured, nominal, search.current,
                  search.chosen, search.rounds, split_s, dict(zip(replay.channels, replay.scale.tolist(), strict=True)),
                  time.perf_counter() - t_start, {"replay": replay, "P": search.P}, search.initial, replay.mode,
                  {"open_rms": open_rms, "shooting_rms": shoot_rms}, search.aliases, unexpl, where, joint=joint,
                  judgement=judgement)


def _judge(search: Search, cfg: Any, validation: Sequence[tuple[Recording, str | Path]]) -> Judgement:
    """The search's chosen terms judged on held-out data (``judge.judge_findings``); the search then
    holds what was kept (refitted, with its start state and outputs), and no near-alias of a rejected
    term is said."""
    j = judge_findings(search.replay, cfg, search.P0, search.chosen_terms, search.chosen, [search.n_train], validation,
                       search.progress)
    if j.rejected:
        out = {t for r in j.rejected for t in r.terms}
        search.chosen_terms, search.chosen, search.P = j.terms, j.fits, j.P
        search.aliases = [a for a in search.aliases if a.chosen not in out]
        search.initial = estimate_initial_state(search.replay, j.P, search.n_train)
        search.current = search.replay.simulate(j.P)
    return j
