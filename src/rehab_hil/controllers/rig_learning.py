"""Learning on the rig: the model-learned feedforward is trial 0, each open-close cycle on the rig the next.

The feedforward a ``model_based`` controller starts with is learned on the model
(``controllers/feedforward.py``); a rig that differs from the model (a warmer room, a lower supply,
a wire with less pre-strain, a draft) tracks worse with it, cycle after cycle, and the feedback is
weak by design. Here the table keeps learning from the rig's own measured tracking error with the
model learning's own step (``ilc_step``: the same leads, leak and Q-filter), the rig's gain, and a
forgetting factor that pulls the learned correction back toward the model's table (a noisy cycle
or a transient leaves no lasting mark):

    u_{j+1} = envelope( ilc_step( u_0 + (1 - forgetting) (u_j - u_0), e_j ) )

The envelope keeps every update inside the rig's safety limits before it is used: the effort
bounds (the clip in ``ilc_step``), the continuous-heating limit (no run of the table longer than
``max_heating_s`` less the margins: a rest is planned where the guard would cut anyway) and the
temperature budget (the effort the updated table would apply, run through the model's thermal
part, the observer the controller already carries; an update that would exceed it is scaled back
by bisection). ``RigLearner`` only computes: the runtime (``service/rig_learning.py``) collects the
error off the control path, runs ``update`` on a worker thread and swaps the table at a cycle
boundary.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from rehab_hil.controllers.feedforward import LearningSettings, ilc_step
from rehab_hil.models.system import Diagram, Part

__all__ = ["RigLearner", "RigLearningSpec", "fit_heating_runs"]

_BISECTIONS = 6  # scale-back steps: the accepted share of an update is within 1/64 of the largest that fits


@dataclass(frozen=True)
class RigLearningSpec:
    """What the learning on the rig needs of a built controller (set by ``model_based``)."""

    learning: LearningSettings  # the model learning's leads, Q-filter, leak and tolerance
    gain_per_deg: float  # the rig's ILC gain [actuator unit / deg]
    forgetting: float  # share of the learned correction forgotten per cycle (toward the model's table) [0..1)
    bounds: tuple[float, float]  # the effort the table may hold [actuator unit]
    step_s: float  # one table row [s]
    period_s: float  # one open-close cycle [s]
    swap_s: float  # where in the period tables are swapped (the middle of the closed hold) [s]
    heating_limit_s: float  # the longest continuous run the controller may command [s]
    rest_s: float  # the guard's rest [s]
    budget_c: float | None = None  # the temperature budget [C] (heated actuators)
    observer: Sequence[Part] = ()  # the model's thermal part (reads ``effort`` and ``constants``)
    effort: str = ""
    temperature: str = ""  # the observer's temperature signal
    constants: Mapping[str, float] = field(default_factory=dict)
    plan_key: str = ""  # the model plan's fingerprint: a stored table belongs to one plan
    enabled: bool = True  # the config's ``rig_learning``: a session learns unless told otherwise
    deadband_deg: float = 0.0  # an error this small teaches nothing (one encoder count: below it is quantisation)

    @property
    def n(self) -> int:
        return max(1, round(self.period_s / self.step_s))


def fit_heating_runs(table: np.ndarray, limit_steps: int, rest_steps: int) -> np.ndarray:
    """``table`` with a rest of ``rest_steps`` zeros planned into every run of nonzero effort
    (wrapped around the period) longer than ``limit_steps``, where the heating guard would rest."""
    on = table != 0.0
    n = len(table)
    if not on.any() or (on.all() and limit_steps >= n):
        # nothing on; or on throughout a period shorter than the limit (a motor holding against its spring):
        # one run as long as the session, which no table can shorten where it matters; the guard rests it at
        # its limit. Planting a rest in every period here dipped the Finger Extensor's closed hold (0.05 ->
        # 0.10 deg RMSE on the nominal rig)
        return table
    out = np.array(table, float)
    if on.all():  # a run around the whole period: its rest at the start, so the wrap joins no runs
        out[:rest_steps] = 0.0
        start = 0
    else:
        start = int(np.flatnonzero(~on)[0])  # begin at a rest so no run is split by the wrap
    out = np.roll(out, -start)
    run = 0
    k = 0
    while k < n:
        if out[k] == 0.0:
            run = 0
        else:
            run += 1
            if run >= limit_steps:
                out[k:k + rest_steps] = 0.0
                k += rest_steps
                run = 0
                continue
        k += 1
    return np.roll(out, start)


class RigLearner:
    """The update from one cycle on the rig, inside the envelope; see the module docstring."""

    def __init__(self, spec: RigLearningSpec, base: np.ndarray) -> None:
        self.spec = spec
        self.base = np.asarray(base, float).copy()  # trial 0: the model's table
        self._observer: Any = None

    def prepare(self) -> None:
        """Everything slow done once, before the session's loop starts: scipy's filter import
        (~1 s), the observer's engine (generated and compiled or loaded by numba) and one update.
        Done later, on the worker, it would hold the GIL for a second and stall the loop (a
        watchdog trip 0.2 s after the first update on a loaded machine, measured)."""
        base = self.base
        self.update(base, np.zeros_like(base), np.clip(base, *self.spec.bounds))
        if self.spec.observer and self.spec.budget_c is not None:
            self.predicted_peak_c(np.clip(base, *self.spec.bounds))

    def update(self, table: np.ndarray, error: np.ndarray, effort: np.ndarray, cut: np.ndarray | None = None
               ) -> tuple[np.ndarray, dict[str, float]]:
        """The next table from the current ``table``, the measured ``error`` (reference - angle),
        the applied ``effort`` and where the limit ``cut`` the demand, per row over one cycle, and
        what the update did: the cycle's RMSE, the change, the share of it kept (1: all; less:
        scaled back for the temperature budget) and the peak temperature the observer predicts.
        Where the limit cut the demand (the ceiling, the guard) the table does not rise: the
        effort there is the envelope's, and a table above it would only wind up (anti-windup)."""
        s = self.spec
        error = np.nan_to_num(np.asarray(error, float))
        rmse = float(np.sqrt(np.mean(error**2)))
        # soft threshold: within a count of the reference the encoder cannot tell better from worse (the
        # Finger Extensor's count is 0.18 deg, its nominal tracking error 0.05 deg RMS: flickers, not a trend)
        error = np.sign(error) * np.maximum(np.abs(error) - s.deadband_deg, 0.0)
        kept = self.base + (1.0 - s.forgetting) * (table - self.base)
        proposed = ilc_step(kept, error, s.step_s, s.bounds, s.learning, True, s.gain_per_deg)
        if cut is not None:
            proposed = np.where(cut, np.minimum(proposed, np.maximum(table, effort)), proposed)
        proposed = self.fit(proposed)
        share, peak = self._within_budget(table, proposed, np.asarray(effort, float))
        new = self.fit(table + share * (proposed - table)) if share < 1.0 else proposed
        info = {"learn_error_rmse_deg": rmse,
                "learn_change_rms": float(np.sqrt(np.mean((new - table) ** 2))),
                "learn_share": float(share), "learn_predicted_peak_c": float(peak),
                "learn_longest_run_s": longest_run_s(new, s.step_s)}
        return new, info

    def fit(self, table: np.ndarray) -> np.ndarray:
        """``table`` inside the effort bounds, with a rest planned into every run longer than the heating limit."""
        s = self.spec
        return fit_heating_runs(np.clip(table, *s.bounds), max(1, int(s.heating_limit_s / s.step_s)),
                                max(1, round(s.rest_s / s.step_s)))

    def _within_budget(self, table: np.ndarray, proposed: np.ndarray, effort: np.ndarray) -> tuple[float, float]:
        """The largest share of the change ``proposed - table`` whose predicted applied effort (the
        measured one plus the change) keeps the observer within the budget, and its peak."""
        s = self.spec
        if s.budget_c is None or not s.observer:
            return 1.0, float("nan")

        def peak(share: float) -> float:
            return self.predicted_peak_c(np.clip(effort + share * (proposed - table), *s.bounds))

        full = peak(1.0)
        if full <= s.budget_c:
            return 1.0, full
        lo, hi, at_lo = 0.0, 1.0, peak(0.0)
        for _ in range(_BISECTIONS):
            mid = 0.5 * (lo + hi)
            p = peak(mid)
            if p <= s.budget_c:
                lo, at_lo = mid, p
            else:
                hi = mid
        return lo, at_lo

    def predicted_peak_c(self, effort: np.ndarray) -> float:
        """The hottest the model's thermal part gets over the second of two cycles of ``effort``
        from ambient (one cycle's effort, repeated: the periodic steady state) [C]."""
        s = self.spec
        if self._observer is None:
            d = Diagram(list(s.observer), inputs=(s.effort, *s.constants))
            self._observer = d.compile(s.step_s, 1)
        n = len(effort)
        given = {s.effort: np.tile(effort, 2), **{k: v for k, v in s.constants.items()}}
        res = self._observer.simulate(2 * n, {k: v for k, v in given.items()
                                              if k in self._observer.input_names}, outputs=[s.temperature])
        return float(np.max(res[s.temperature][n:]))


def longest_run_s(table: np.ndarray, step_s: float) -> float:
    """The longest run of nonzero values, wrapped around the period [s]."""
    on = np.asarray(table) != 0.0
    if on.all():
        return len(on) * step_s
    if not on.any():
        return 0.0
    rolled = np.roll(on, -int(np.flatnonzero(~on)[0]))
    edges = np.flatnonzero(np.diff(np.concatenate([[0], rolled.astype(np.int8), [0]])))
    return float(np.max(edges[1::2] - edges[::2]) * step_s)
