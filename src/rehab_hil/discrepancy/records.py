"""Several records of one plant replayed with one parameter vector, each from its own start state.

A ``RecordSet`` stands where the workflow's fits and scores take one ``Replay``: it answers
``simulate`` and ``residual`` on a virtual record made of every record's fit part, one after
another, followed by every record's held-out part, so a fit over ``n_train`` samples fits all fit
parts at once and a score over the rest scores every held-out part (one information criterion over
all records). Each record keeps its own replay (start state, replay mode, fit start); every replay
comes from the same config, so a parameter vector means the same in each. The records are replayed
side by side on threads (the compiled engine releases the GIL). The residual is scaled by
one scale per channel (the root mean square of the records' spreads), so a record counts by its
samples, not by how far it moved.

The gap per record is measured one way for estimation and validation records alike (``gap``):
each record replayed whole from its own start state, never re-anchored (no multiple shooting; a
recorded controller's loop is replayed as the config declares), per-channel RMSE; what
``rehab-hil replay`` prints for the record.
"""

from __future__ import annotations

import functools
import os
from collections.abc import Mapping
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from rehab_hil.discrepancy.initial_state import estimate_initial_state
from rehab_hil.discrepancy.replay import NOISY_SPREAD, Replay, channel_metrics
from rehab_hil.discrepancy.verdict import noise_floor

__all__ = ["GAP_MEASURE", "RecordSet", "from_own_start", "gap", "whole_record"]

GAP_MEASURE = ("whole-record replay from the record's own start state, never re-anchored to the measurements "
               "(what `replay` prints)")


@functools.cache
def _pool() -> ThreadPoolExecutor:
    """Threads that replay the records side by side: the compiled engine releases the GIL (``nogil``)."""
    return ThreadPoolExecutor(max_workers=max(1, min(4, os.cpu_count() or 1)), thread_name_prefix="records")


def from_own_start(replay: Replay, P: np.ndarray, n_fit: int, mode: str | None = None) -> dict[str, np.ndarray]:
    """The model's outputs over the whole record from its own start state estimated under ``P`` on the
    first ``n_fit`` samples, in ``mode`` (None: the replay's own); the replay's start state, anchoring
    and fit start are put back (a model is judged from the start it would have, ``judge``)."""
    x0, xd0, start, gain = replay.x0, replay.xd0, replay.fit_start, replay.anchor_gain
    try:
        estimate_initial_state(replay, P, n_fit)
        return replay.simulate(P, mode=mode)
    finally:
        replay.x0, replay.xd0, replay.fit_start, replay.anchor_gain = x0, xd0, start, gain


def whole_record(replay: Replay, P: np.ndarray) -> dict[str, np.ndarray]:
    """The model's outputs over the whole record from its own start state estimated under ``P``,
    never re-anchored (``GAP_MEASURE``); the replay's start state, anchoring and fit start are put back."""
    return from_own_start(replay, P, replay.t.size, "open")


def gap(replay: Replay, P: np.ndarray) -> dict[str, dict[str, float]]:
    """Per-channel RMSE, MAE and largest error of ``whole_record`` (``GAP_MEASURE``)."""
    sim = whole_record(replay, P)
    return {c: channel_metrics(replay.measured[c], sim[c]) for c in replay.channels}


@dataclass
class RecordSet:
    """Records of one plant and config, replayed together (module docstring)."""

    replays: list[Replay]
    n_trains: list[int]  # per record: samples of its fit part
    names: list[str]
    scale: np.ndarray = field(init=False)
    fit_weight: np.ndarray = field(init=False)
    measured: dict[str, np.ndarray] = field(init=False)
    t: np.ndarray = field(init=False)
    n_train: int = field(init=False)  # samples of the virtual record's fit part (all fit parts)

    def __post_init__(self) -> None:
        first = self.replays[0]
        chans = first.channels
        for r, name in zip(self.replays[1:], self.names[1:], strict=True):
            if r.channels != chans or r.nominal_params().shape != first.nominal_params().shape:
                raise ValueError(f"{name}: its channels {r.channels} differ from the first record's {chans}; "
                                 "records fitted together must carry the same columns")
        spreads = np.array([r.scale for r in self.replays])
        self.scale = np.sqrt(np.mean(spreads**2, axis=0))
        floors = np.array([[noise_floor(r.measured[c]) for c in chans] for r in self.replays]).max(axis=0)
        self.fit_weight = self.scale / np.maximum(self.scale, NOISY_SPREAD * floors)
        self.n_train = int(sum(self.n_trains))
        self.measured = {c: np.concatenate([self.replays[i].measured[c][sl] for i, sl in self._pieces()])
                         for c in chans}
        t, off = [], 0.0
        for i, sl in self._pieces():
            r = self.replays[i]
            seg = r.t[sl] - r.t[sl][0]
            t.append(seg + off)
            off += float(seg[-1]) + float(np.median(np.diff(r.t)))
        self.t = np.concatenate(t)

    # what the fits and scores ask of a replay --------------------------------------------------
    @property
    def channels(self) -> list[str]:
        return self.replays[0].channels

    @property
    def spec(self) -> Any:
        return self.replays[0].spec

    @property
    def cfg(self) -> Any:
        return self.replays[0].cfg

    @property
    def ports(self) -> Any:
        return self.replays[0].ports

    @property
    def system(self) -> Any:
        return self.replays[0].system

    @property
    def candidates(self) -> list[Any]:
        return self.replays[0].candidates

    @property
    def kinds(self) -> dict[str, str]:
        return self.replays[0].kinds

    @property
    def n_diagram_params(self) -> int:
        return self.replays[0].n_diagram_params

    @property
    def loop(self) -> str:
        return self.replays[0].loop

    @property
    def fit_start(self) -> int:
        return 0  # each record's own fit start is applied in ``simulate`` (its skipped samples match)

    @property
    def mode(self) -> str:
        modes = sorted({r.mode for r in self.replays})
        return modes[0] if len(modes) == 1 else "+".join(modes)

    def nominal_params(self) -> np.ndarray:
        return self.replays[0].nominal_params()

    def with_effects(self, base: np.ndarray, values: Mapping[str, Mapping[str, float]]) -> np.ndarray:
        return self.replays[0].with_effects(base, values)

    def index(self, effect: str, param: str) -> int:
        return self.replays[0].index(effect, param)

    def input_scale_index(self, name: str) -> int:
        return self.replays[0].input_scale_index(name)

    def simulate(self, P: np.ndarray, n_meas: int | None = None, mode: str | None = None,
                 sensed: bool = True) -> dict[str, np.ndarray]:
        """Outputs on the virtual record: its fit part only when ``n_meas`` is at most ``n_train``
        (each record run to the end of its fit part; the samples before a record's fit start read as
        measured), else the whole virtual record."""
        short = n_meas is not None and n_meas <= self.n_train

        def one(k: int) -> dict[str, np.ndarray]:
            r = self.replays[k]
            sim = r.simulate(P, self.n_trains[k] if short else None, mode, sensed)
            for c in self.channels:
                sim[c][:r.fit_start] = r.measured[c][:r.fit_start]
            return sim

        parts = list(_pool().map(one, range(len(self.replays))))
        pieces = self._pieces(fit_only=short)
        out = {c: np.concatenate([parts[i][c][sl] for i, sl in pieces]) for c in self.channels}
        if n_meas is not None:
            out = {c: v[:n_meas] for c, v in out.items()}
        return out

    def residual(self, sim: Mapping[str, np.ndarray], sl: slice = slice(None), weighted: bool = False) -> np.ndarray:
        """Scaled residual on the virtual record, shape (channels, samples), as ``Replay.residual``."""
        r = np.vstack([(sim[c][sl] - self.measured[c][sl]) / s for c, s in zip(self.channels, self.scale, strict=True)])
        return r * self.fit_weight[:, None] if weighted else r

    def drop_cache(self) -> None:
        for r in self.replays:
            r.drop_cache()

    # per record ----------------------------------------------------------------------------------
    def estimate_starts(self, P: np.ndarray) -> list[Any]:
        """Each record's start state under ``P`` (``initial_state``); returns them in record order."""
        return [estimate_initial_state(r, P, n) for r, n in zip(self.replays, self.n_trains, strict=True)]

    def gaps(self, P: np.ndarray) -> list[dict[str, dict[str, float]]]:
        """``gap`` of every record under ``P``."""
        return [gap(r, P) for r in self.replays]

    def _pieces(self, fit_only: bool = False) -> list[tuple[int, slice]]:
        """(record, samples) of the virtual record in order: the fit parts, then the held-out parts."""
        fit = [(i, slice(0, n)) for i, n in enumerate(self.n_trains)]
        if fit_only:
            return fit
        return fit + [(i, slice(n, r.t.size)) for i, (r, n) in enumerate(zip(self.replays, self.n_trains, strict=True))
                      if n < r.t.size]
