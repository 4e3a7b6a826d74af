"""When to replay by multiple shooting (prediction error) rather than open loop (simulation error).

Open loop, the model runs once over the whole record from its initial state: right for a plant
that forgets its start (a heated wire cools to ambient, a spring returns the finger). A plant that
integrates (the Finger Extensor's weak spring, stick-slip that can hold it anywhere) replayed on
the inputs of a closed-loop record drifts: the controller corrected the real plant, nothing
corrects the model, and a tiny mismatch becomes a large slow offset that hides every effect.
Shooting (``Replay.shoot``) cuts the record into segments of ``SEGMENT_S``; at each boundary the
states the measurements match (``initial_state``: the angle, a measured current or temperature) are
re-anchored to the measured values, the others carried over, and the parameters are fitted on the
residual of all segments jointly. The workflow uses shooting when the nominal model's open-loop
residual on some channel is more than ``DRIFT_RATIO`` times its shooting residual and shooting
makes no channel worse: even a drift of a few tenths of a degree hides a 1 deg backlash in an
open-loop replay of a closed-loop record (measured on the benchmark), while on a plant that forgets
its start (the SMA wire) shooting only adds anchoring noise and open loop stays.
"""

from __future__ import annotations

import numpy as np

from rehab_hil.discrepancy.replay import Replay
from rehab_hil.discrepancy.selection import bounded

__all__ = ["DRIFT_RATIO", "SEGMENT_S", "choose_mode"]

SEGMENT_S = 1.0  # long enough to show friction, delay and backlash within a segment, short against drift
DRIFT_RATIO = 1.1  # a channel's open-loop residual this many times its shooting residual: drift shows


def choose_mode(replay: Replay, P: np.ndarray, n_train: int) -> tuple[str, float, float]:
    """("open" or "shooting", open-loop RMS, shooting RMS) of the scaled residual on the fit part;
    shooting when some channel's open-loop RMS exceeds ``DRIFT_RATIO`` times its shooting RMS and no
    channel's shooting RMS exceeds ``DRIFT_RATIO`` times its open-loop RMS (anchoring noise)."""
    replay.use_segments(SEGMENT_S)
    sl = slice(0, n_train)
    r_open = replay.residual(replay.simulate(P, n_train, mode="open"), sl)
    if replay.anchor_gain is None or not np.any(replay.anchor_gain):
        return "open", float(np.sqrt(np.mean(_rms(r_open) ** 2))), float("nan")
    r_shoot = replay.residual(replay.simulate(P, n_train, mode="shooting"), sl)
    o, s = _rms(r_open), _rms(r_shoot)
    drift = bool(np.any(o > DRIFT_RATIO * s)) and not bool(np.any(s > DRIFT_RATIO * o))
    return ("shooting" if drift else "open"), float(np.sqrt(np.mean(o**2))), float(np.sqrt(np.mean(s**2)))


def _rms(r: np.ndarray) -> np.ndarray:
    r = bounded(r)
    return np.sqrt(np.mean(r**2, axis=1))
