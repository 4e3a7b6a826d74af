"""The discrepancy workflow on several records at once, effects chosen as a set (issue 38).

1. Each record is bound to the plant (``Replay``) and gets its own start state (``Options.start``
   per record: at rest, estimated, or at rest when its data show it) and replay mode
   from the data under the nominal model; its first ``1 - holdout_fraction`` fits, the rest is held
   out. The records together are a ``records.RecordSet``: one parameter vector for all.
2. The candidate terms (library effects that attach, declared parameters) are searched as sets
   (``subsets.SetSearch``) under one held-out BIC over all records.
3. The chosen set's start states are estimated again under it, and the set refitted from them;
   the set is judged on held-out data (``judge``: the validation records, else the records'
   held-out parts), a member that makes them worse than its given value rejected and the rest
   refitted; then every declared parameter is fitted with what was kept (``identify``), and a value
   that ends on its bound is said to be on its bound (``bounds``), not reported as a finding.
4. The gap per record (nominal and augmented) is measured as ``records.GAP_MEASURE``, the measure
   a validation record and ``rehab-hil replay`` use.
"""

from __future__ import annotations

import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from rehab_hil.discrepancy.bounds import at_bound
from rehab_hil.discrepancy.candidates import candidate_terms
from rehab_hil.discrepancy.experiments import lacking, mend_suggestions
from rehab_hil.discrepancy.fitting import Fit, Term, fit_joint
from rehab_hil.discrepancy.identify import identify_jointly
from rehab_hil.discrepancy.initial_state import estimate_initial_state
from rehab_hil.discrepancy.judge import Judgement, judge_findings
from rehab_hil.discrepancy.records import GAP_MEASURE, RecordSet
from rehab_hil.discrepancy.replay import Replay
from rehab_hil.discrepancy.result import Alias, Candidate, Result, Round
from rehab_hil.discrepancy.selection import improvement
from rehab_hil.discrepancy.shooting import choose_mode
from rehab_hil.discrepancy.subsets import SetSearch
from rehab_hil.discrepancy.verdict import experiment, unexplained
from rehab_hil.effects import EFFECTS
from rehab_hil.interchange import Recording
from rehab_hil.plants import get_plant

__all__ = ["find_in_records"]


def find_in_records(cfg: Any, recs: Sequence[Recording], paths: Sequence[str | Path], progress: Any,
                    options: Any, validation: Sequence[tuple[Recording, str | Path]] = ()) -> Result:
    """Run the set workflow on loaded records (module docstring); ``options`` as ``workflow.Options``,
    ``validation`` as ``workflow.find_missing_effects`` takes it."""
    t_start = time.perf_counter()
    spec = get_plant(cfg.plant)
    progress.start(f"replay nominal model on {len(recs)} records", len(recs))
    records = _bind(spec, cfg, recs, paths, options, progress)
    P0 = records.nominal_params()
    nominal = records.simulate(P0)
    terms = candidate_terms(records.replays[0], options, refinements=True)
    progress.start(f"screening {len(terms)} candidate terms and their sets", None)
    search = SetSearch(records, terms, P0, records.n_train, progress.advance, max_terms=options.max_effects)
    best = search.run()
    judgement, starts = _refit_and_judge(records, cfg, P0, [t for t in terms if t.name in best.names], best.fits,
                                         best.P, validation, progress)
    chosen_terms, fits, P = judgement.terms, judgement.fits, judgement.P
    current = records.simulate(P)
    joint = None
    if options.joint and options.parameters:
        progress.start("joint identification of every parameter", None)
        joint = identify_jointly(records, P0, chosen_terms, fits, records.n_train, progress.advance)
    progress.start("the gap per record", None)
    gaps = {"measure": GAP_MEASURE, "records": [
        {"data": name, "nominal": g0, "augmented": g1, "start": _start(s)}
        for name, g0, g1, s in zip(records.names, records.gaps(P0), records.gaps(P), starts, strict=True)]}
    for r, s in zip(records.replays, starts, strict=True):  # the fit's start states stay the result's
        r.x0, r.xd0 = s.x0, s.xd0
    records.drop_cache()
    split_s = float(records.t[records.n_train]) if records.n_train < records.t.size else float(records.t[-1])
    unexpl, where = unexplained(records, current, split_s, records.kinds)
    res = Result(spec.name, records.channels, records.kinds, records.t, records.measured, nominal, current, fits,
                 [_round(search, records)], split_s, dict(zip(records.channels, records.scale.tolist(), strict=True)),
                 time.perf_counter() - t_start, {"replay": records, "P": P}, starts[0], records.mode, {},
                 _aliases(search, {t for r in judgement.rejected for t in r.terms}), unexpl, where, joint=joint,
                 judgement=judgement)
    res.gaps = gaps
    res.bounds = at_bound(chosen_terms, fits, joint)
    res.lacking = lacking(records)
    mend_suggestions(res.aliases, records)
    res.dropped = list(search.dropped)
    return res


def _refit_and_judge(records: RecordSet, cfg: Any, P0: np.ndarray, chosen: list[Term], best_fits: Sequence[Fit],
                     best_P: np.ndarray, validation: Sequence[tuple[Recording, str | Path]],
                     progress: Any) -> tuple[Judgement, list[Any]]:
    """The chosen set refitted from each record's start state under it, then judged on held-out data
    (``judge``); returns the judgement and each record's start state under what was kept."""
    progress.start("refit of the chosen set from each record's new start state", None)
    starts = records.estimate_starts(best_P)
    fits = (fit_joint(records, P0, chosen, [f.params for f in best_fits], records.n_train, progress.advance)
            if chosen else [])
    judgement = judge_findings(records, cfg, P0, chosen, fits, records.n_trains, validation, progress)
    if judgement.rejected:  # the start states under what was kept
        starts = records.estimate_starts(judgement.P)
    return judgement, starts


def _bind(spec: Any, cfg: Any, recs: Sequence[Recording], paths: Sequence[str | Path], options: Any,
          progress: Any) -> RecordSet:
    """Each record's replay, fit part, start state and replay mode; the records as one set."""
    replays, n_trains = [], []
    for rec, path in zip(recs, paths, strict=True):
        replay = Replay.build(spec, cfg, rec, path, closed_loop=options.closed_loop)
        replay.start = options.start  # each record's own: at rest, estimated, or found from its data
        N = replay.t.size
        n_train = max(2, min(round((1.0 - options.holdout_fraction) * N),
                             int(np.searchsorted(replay.t, options.fit_max_s))))
        P0 = replay.nominal_params()
        estimate_initial_state(replay, P0, n_train)
        mode = "open" if replay.loop else choose_mode(replay, P0, n_train)[0]
        replay.mode = mode if options.mode == "auto" else options.mode
        replays.append(replay)
        n_trains.append(n_train)
        progress.advance()
    return RecordSet(replays, n_trains, [str(p) for p in paths])


def _start(init: Any) -> dict[str, Any]:
    """A record's start state in the report: at rest ("option", "data") or estimated, and how."""
    return {"at_rest": init.at_rest, "estimated": init.estimated, "summary": init.describe()}


def _round(search: SetSearch, records: RecordSet) -> Round:
    """The refined sets as one round of candidates (a set's name joins its members with " + ")."""
    base = search.fitted[frozenset()]
    cands = []
    for key, s in sorted(search.fitted.items(), key=lambda kv: kv[1].score.bic):
        if not key:
            continue
        params = {f"{f.effect}.{k}": v for f in s.fits for k, v in f.params.items()}
        stderr = {f"{f.effect}.{k}": v for f in s.fits for k, v in f.stderr.items()}
        kind = "effect" if any(f.kind == "effect" for f in s.fits) else "parameter"
        fit = type(s.fits[0])(" + ".join(s.names), params, stderr, {}, s.fits[0].train_cost,
                              s.fits[0].n_simulations, s.P, kind)
        chosen = search.chosen is not None and key == frozenset(search.chosen.names)
        cands.append(Candidate(fit, s.score, s.score.bic - base.score.bic, improvement(s.score, base.score), chosen))
    name = " + ".join(search.chosen.names) if search.chosen is not None and search.chosen.names else None
    return Round(base.score, cands, name)


def _aliases(search: SetSearch, rejected: set[str]) -> list[Alias]:
    """Near-aliases of the chosen set: each pair once, none of a member the held-out data rejected."""
    descriptions = {e.name: e.description for e in EFFECTS.values()}
    seen, out = set(), []
    for a, b, d in search.near_aliases():
        if frozenset((a, b)) in seen or a in rejected:
            continue
        seen.add(frozenset((a, b)))
        out.append(Alias(1, a, b, d, experiment(a, b, descriptions)))
    return out

