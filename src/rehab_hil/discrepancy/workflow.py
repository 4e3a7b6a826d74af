"""The discrepancy workflow: replay, localise, fit every candidate, select, repeat.

The first ``1 - holdout_fraction`` of the record fits the parameters; the rest is held out and
scores the candidates (``selection``). A chosen effect stays in the model (its parameters fixed)
and the search repeats for the next while a candidate is still significantly better.
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from rehab_hil.discrepancy.fitting import Fit, fit_effect
from rehab_hil.discrepancy.replay import Replay
from rehab_hil.discrepancy.result import Candidate, Result, Round
from rehab_hil.discrepancy.selection import bic, effective_fraction, improvement, is_significant
from rehab_hil.interchange import Recording
from rehab_hil.plants import get_plant

__all__ = ["Candidate", "Options", "Progress", "Result", "Round", "find_missing_effects"]


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
    max_effects: int = 2


def find_missing_effects(cfg: Any, rec: Recording, data_path: str | Path = "<data>",
                         progress: Progress | None = None, options: Options | None = None) -> Result:
    """Run the workflow on a loaded config and recording; see the module docstring."""
    t_start = time.perf_counter()
    progress = progress or Progress()
    options = options or Options()
    spec = get_plant(cfg.plant)
    progress.start("replay nominal model", 1)
    replay = Replay.build(spec, cfg, rec, data_path)
    N = replay.t.size
    n_train = max(2, min(round((1.0 - options.holdout_fraction) * N),
                         int(np.searchsorted(replay.t, options.fit_max_s))))
    hold = slice(n_train, N)
    P = replay.nominal_params()
    nominal = replay.simulate(P)
    progress.advance()
    current, n_params = nominal, 0
    chosen: list[Fit] = []
    rounds: list[Round] = []
    for _ in range(options.max_effects):
        r_cur = replay.residual(current, hold)
        frac = effective_fraction(r_cur)
        base = bic(r_cur, n_params, frac)
        cands: list[Candidate] = []
        todo = [e for e in replay.candidates if e.name not in {f.effect for f in chosen}]
        for eff in todo:
            progress.start(f"round {len(rounds) + 1}: fitting {eff.name}", None)
            fit = fit_effect(replay, P, eff, n_train, progress.advance)
            sim = replay.simulate(fit.P)
            sc = bic(replay.residual(sim, hold), n_params + len(eff.params), frac)
            cands.append(Candidate(fit, sc, sc.bic - base.bic, improvement(sc, base), is_significant(sc, base), sim))
        cands.sort(key=lambda c: (not c.significant, c.score.bic))  # the best significant one first
        pick = cands[0] if cands and cands[0].significant else None
        rounds.append(Round(base, cands, pick.fit.effect if pick else None))
        if pick is None:
            break
        chosen.append(pick.fit)
        assert pick.sim is not None
        P, current, n_params = pick.fit.P, pick.sim, pick.score.n_params
    for rd in rounds:
        for c in rd.candidates:
            c.sim = None
    kinds = {c: replay.ports.measured_kind(c) or "" for c in replay.channels}
    return Result(spec.name, replay.channels, kinds, replay.t, replay.measured, nominal, current, chosen, rounds,
                  float(replay.t[n_train]) if n_train < N else float(replay.t[-1]),
                  dict(zip(replay.channels, replay.scale.tolist(), strict=True)),
                  time.perf_counter() - t_start, {"replay": replay, "P": P})
