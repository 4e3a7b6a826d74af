"""Whether a fitted candidate is worth naming: the one rule of the workflow and the twin's diagnosis.

A candidate is named when it beats the current model (``selection``: it cuts some channel's
held-out RMS error by ``MIN_IMPROVEMENT``; offline also a BIC lower by ``MIN_DELTA_BIC``), it is
more than a rounding of "off" (``relevant``), and, for a sensor effect, only on a channel whose
own error the noise cannot account for (``sensor_demanded``).
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from rehab_hil.discrepancy.fitting import Fit, Term
from rehab_hil.discrepancy.replay import Replay
from rehab_hil.discrepancy.selection import (
    MIN_IMPROVEMENT,
    RESOLUTION_FLOOR,
    Score,
    bic,
    improvement,
    is_significant,
)
from rehab_hil.discrepancy.verdict import unexplained_channels
from rehab_hil.effects import EFFECTS

__all__ = ["demanding_channels", "relevant", "score", "sensor_demanded", "significant"]


def score(replay: Replay, sim: dict[str, np.ndarray], hold: slice, n_params: int, frac: float) -> Score:
    """The held-out score (``selection.bic``) of a model's outputs ``sim`` with ``n_params`` fitted."""
    return bic(replay.residual(sim, hold), n_params, frac, replay.fit_weight)


def demanding_channels(replay: Replay, current: dict[str, np.ndarray], hold: slice) -> set[str]:
    """Channels whose held-out error under the current model the noise cannot account for."""
    rms = {c: float(np.sqrt(np.mean((current[c][hold] - replay.measured[c][hold]) ** 2))) for c in replay.channels}
    return set(unexplained_channels(replay.channels, {c: replay.measured[c][hold] for c in replay.channels}, rms))


def sensor_demanded(replay: Replay, term: Term, demanding: set[str]) -> bool:
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


def relevant(replay: Replay, term: Term, fit: Fit, sim: dict[str, np.ndarray], hold: slice, base: Score) -> bool:
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


def significant(replay: Replay, term: Term, candidate: Score, base: Score, demanding: set[str],
                is_relevant: Callable[[], bool], bic_margin: bool = True) -> bool:
    """Is the fitted ``term`` (scored ``candidate`` against the current model's ``base``) worth naming?

    ``bic_margin``: the BIC must also fall by ``MIN_DELTA_BIC`` (offline; a twin window of a few
    seconds has a handful of effective samples, and the monitor has already said there is a
    mismatch). ``is_relevant`` is asked only when the scores pass: it may cost a simulation."""
    beats = is_significant(candidate, base) if bic_margin else improvement(candidate, base) >= MIN_IMPROVEMENT
    return beats and is_relevant() and sensor_demanded(replay, term, demanding)
