"""The discrepancy workflow: replay, localise, fit every candidate, select, repeat.

The first ``1 - holdout_fraction`` of the record fits the parameters; the rest is held out and
scores the candidates (``selection``). A chosen effect stays in the model (its parameters fixed)
and the search repeats for the next while a candidate is still significantly better.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from rehab_hil.config import load_config
from rehab_hil.discrepancy.fitting import Fit, fit_effect
from rehab_hil.discrepancy.replay import Replay, channel_metrics
from rehab_hil.discrepancy.selection import Score, bic, effective_fraction, improvement, is_significant
from rehab_hil.interchange import Recording, read_csv
from rehab_hil.plants import get_plant

__all__ = ["Candidate", "Options", "Progress", "Result", "Round", "find_missing_effects", "run"]


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


@dataclass
class Candidate:
    fit: Fit
    score: Score
    delta_bic: float  # versus the model of this round (negative: better)
    improvement: float  # largest relative cut of a channel's held-out RMS error
    significant: bool
    sim: dict[str, np.ndarray] | None = field(default=None, repr=False)  # full-record outputs


@dataclass
class Round:
    baseline: Score
    candidates: list[Candidate]  # best first
    chosen: str | None


@dataclass
class Result:
    plant: str
    channels: list[str]
    t: np.ndarray
    measured: dict[str, np.ndarray]
    nominal: dict[str, np.ndarray]
    augmented: dict[str, np.ndarray]
    chosen: list[Fit]
    rounds: list[Round]
    split_s: float
    scale: dict[str, float]
    wall_s: float = 0.0
    extras: dict[str, Any] = field(default_factory=dict)

    @property
    def named(self) -> list[str]:
        return [f.effect for f in self.chosen]

    def metrics(self, which: str, part: str = "all") -> dict[str, dict[str, float]]:
        """Per-channel RMSE/MAE/max error of the nominal or augmented model (all or held-out)."""
        model = self.nominal if which == "nominal" else self.augmented
        m = self.t >= self.split_s if part == "holdout" else np.ones(self.t.size, bool)
        return {c: channel_metrics(self.measured[c][m], model[c][m]) for c in self.channels}


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
    return Result(spec.name, replay.channels, replay.t, replay.measured, nominal, current, chosen, rounds,
                  float(replay.t[n_train]) if n_train < N else float(replay.t[-1]),
                  dict(zip(replay.channels, replay.scale.tolist(), strict=True)),
                  time.perf_counter() - t_start, {"replay": replay, "P": P})


def run(config_path: str | Path, data_path: str | Path, out_dir: str | Path,
        progress: Progress | None = None, options: Options | None = None) -> Result:
    """Load, run the workflow, write the report (report.json, report.md, PNGs, augmented.toml)."""
    from rehab_hil.discrepancy.report import write_report

    cfg = load_config(config_path)
    rec = read_csv(data_path)
    res = find_missing_effects(cfg, rec, data_path, progress, options)
    if progress:
        progress.start("writing report", None)
    write_report(res, Path(config_path), Path(data_path), Path(out_dir))
    return res
