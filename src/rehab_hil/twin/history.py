"""``SessionHistory``: the recent session as the twin processed it, kept for the quick diagnosis,
and the mismatches waiting for their window of it.

Each processed block (sample indices, the model's inputs, the measured channels) and, at each
segment's anchor, the model's state; ``HISTORY_S`` of them (``twin.live``). A diagnosis replays a
window of it from the anchor at the mismatch's start, so its fit starts from the state the twin had
there rather than from an estimate; a mismatch waits until ``diagnose_window_s`` of data after its
start is in.
"""

from __future__ import annotations

from collections import deque
from collections.abc import Iterator, Sequence

import numpy as np

from rehab_hil.interchange import Recording
from rehab_hil.twin.monitor import MismatchEvent

__all__ = ["SessionHistory", "Window"]

Window = tuple[Recording, np.ndarray, np.ndarray]  # a stretch of the session and the model's state at its start


class SessionHistory:
    """The last ``keep`` blocks (``blocks``: index, inputs, measured) and anchors (``anchors``: the
    sample index after a segment's last sample, x, xd) of a model with ``input_names`` and ``channels``
    sampled every ``period_s``; the mismatches (``waiting``) whose ``window_s`` is not in yet."""

    def __init__(self, period_s: float, input_names: Sequence[str], channels: Sequence[str], keep: int,
                 window_s: float) -> None:
        self.period_s, self.input_names, self.channels = period_s, input_names, channels
        self.blocks: deque[tuple[np.ndarray, np.ndarray, np.ndarray]] = deque(maxlen=keep)
        self.anchors: deque[tuple[int, np.ndarray, np.ndarray]] = deque(maxlen=keep)
        self.window_s = window_s
        self.waiting: list[MismatchEvent] = []

    def due(self, now_s: float) -> Iterator[tuple[MismatchEvent, Window]]:
        """The waiting mismatches with ``window_s`` of data after their start in by ``now_s``, one at a
        time with their window; they are no longer waited for (one the history lost is dropped)."""
        for ev in list(self.waiting):
            if now_s < ev.t_s + self.window_s:
                continue
            self.waiting.remove(ev)
            window = self._event_window(ev)
            if window is not None:
                yield ev, window

    def take_pending(self, min_s: float) -> list[tuple[MismatchEvent, Window]]:
        """The mismatches still waiting for their full window (the session ended first), each with the
        window it has, when that is at least ``min_s`` long; they are no longer waited for."""
        out = []
        for ev in self.waiting:
            window = self._event_window(ev)
            if window is not None and window[0].t[-1] - window[0].t[0] >= min_s:
                out.append((ev, window))
        self.waiting = []
        return out

    def _event_window(self, ev: MismatchEvent) -> Window | None:
        """The diagnosis window of a mismatch: ``window_s`` from its start, or what there is."""
        return self.window(ev.t_s, ev.t_s + self.window_s)

    def window(self, start_s: float, end_s: float) -> Window | None:
        """The session from the last anchor at or before ``start_s`` to ``end_s`` on the model's
        signals, and the model's state at its start (None when the history no longer has it)."""
        # a segment's anchor is taken after its last sample (index + 1), and an event's start is that
        # sample's time: the anchor at the start is the one at k0 + 1 (was k0: the window began a
        # segment early, and the change fitted over it was in force 0.25 s before it was)
        k0 = round(start_s / self.period_s) + 1
        start = [a for a in self.anchors if a[0] <= k0]
        if not start:
            return None
        i0, x0, xd0 = start[-1]
        i1 = round(end_s / self.period_s)
        idx = np.concatenate([h[0] for h in self.blocks])
        keep = (idx >= i0) & (idx <= i1)
        if keep.sum() < 10:
            return None
        U = np.concatenate([h[1] for h in self.blocks])[keep]
        Y = np.concatenate([h[2] for h in self.blocks])[keep]
        t = (idx[keep] - i0) * self.period_s
        signals = {n: U[:, j] for j, n in enumerate(self.input_names)}
        signals.update({c: Y[:, j] for j, c in enumerate(self.channels)})
        return Recording(t, signals, rig=True), x0, xd0
