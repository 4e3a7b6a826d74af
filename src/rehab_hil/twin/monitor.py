"""A sequential test on the twin's residuals: CUSUM (Page 1954) on each channel's segment RMS.

Each re-anchored segment gives, per channel, the RMS of (measured - predicted) in the channel's
resolution (encoder or ADC counts): what the model got wrong in one segment from a correct start.
The first ``learn_s`` of a session (after ``settle_s``) set the channel's normal level (mean and
spread of the segment RMS: sensor noise, quantisation and the model's usual error on this rig).
Afterwards the one-sided CUSUM

    g_k = max(0, g_{k-1} + z_k - (mu + max(drift_sigma * sigma, min_excess_counts)))

grows while the residual stays above its normal level and raises a ``model_mismatch`` event when
it passes ``threshold_counts``; the change started where g last left zero (the CUSUM change-point
estimate). After an event the channel learns its new level for ``learn_s`` and is watched again, so
a second change in a session is seen too. An event is not a safety trip.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import asdict, dataclass, field

import numpy as np

from rehab_hil.config import MonitorSettings  # the [twin] table's knobs, defined beside it

__all__ = ["MismatchEvent", "MonitorSettings", "ResidualMonitor"]


@dataclass
class MismatchEvent:
    """A model mismatch: when it started, when it was seen, on which channel, how large."""

    t_s: float  # the estimated start (device time) [s]
    detected_s: float  # when the test passed its threshold [s]
    channel: str
    size: float  # segment RMS residual above the normal level, in the channel's unit
    size_counts: float  # the same in counts
    normal: float  # the normal segment RMS, in the channel's unit
    kind: str = "model_mismatch"
    cause: str = ""  # the likeliest cause, once diagnosed ("" until then)
    candidates: list[dict[str, object]] = field(default_factory=list)

    def as_dict(self) -> dict[str, object]:
        return asdict(self)

    def text(self) -> str:
        """One line for the event channel and the summary."""
        head = (f"{self.channel}: residual {self.size:+.3g} above normal ({self.size_counts:.1f} counts) "
                f"since t = {self.t_s:.2f} s, seen at {self.detected_s:.2f} s")
        return f"{head}; likely {self.cause}" if self.cause else head


class _Channel:
    def __init__(self, name: str, resolution: float) -> None:
        self.name, self.resolution = name, resolution
        self.learning: list[float] = []
        self.learn_from = 0.0
        self.mu = math.nan
        self.sigma = math.nan
        self.first_mu = math.nan  # the session's normal level (the first one learned)
        self.g = 0.0
        self.last_zero_s = 0.0


class ResidualMonitor:
    """CUSUM per channel on the segment RMS residual; ``update`` returns new events."""

    def __init__(self, channels: Sequence[str], resolution: Sequence[float],
                 settings: MonitorSettings | None = None) -> None:
        self.settings = settings or MonitorSettings()
        self.channels = [_Channel(c, float(r)) for c, r in zip(channels, resolution, strict=True)]
        for ch in self.channels:
            ch.learn_from = self.settings.settle_s
        self.events: list[MismatchEvent] = []
        self.statistic = np.zeros(len(self.channels))  # the CUSUM g of each channel, in counts

    @property
    def armed(self) -> bool:
        """Every channel has its normal level and is being watched."""
        return all(math.isfinite(ch.mu) for ch in self.channels)

    def update(self, t_start_s: float, t_end_s: float, rms: Sequence[float]) -> list[MismatchEvent]:
        """One segment [t_start_s, t_end_s] with each channel's RMS residual (channel units)."""
        s = self.settings
        new: list[MismatchEvent] = []
        for i, (ch, r) in enumerate(zip(self.channels, rms, strict=True)):
            z = float(r) / ch.resolution
            if not math.isfinite(z):
                continue
            if not math.isfinite(ch.mu):  # learning the normal level
                if t_start_s >= ch.learn_from:
                    ch.learning.append(z)
                if t_end_s >= ch.learn_from + s.learn_s and len(ch.learning) >= 3:
                    ch.mu = float(np.mean(ch.learning))
                    ch.sigma = float(np.std(ch.learning))
                    if not math.isfinite(ch.first_mu):
                        ch.first_mu = ch.mu
                    ch.learning = []
                    ch.g, ch.last_zero_s = 0.0, t_end_s
                continue
            allowed = ch.mu + max(s.drift_sigma * ch.sigma, s.min_excess_counts)
            ch.g = max(0.0, ch.g + z - allowed)
            if ch.g == 0.0:
                ch.last_zero_s = t_end_s
            self.statistic[i] = ch.g
            if ch.g > s.threshold_counts:
                ev = MismatchEvent(t_s=ch.last_zero_s, detected_s=t_end_s, channel=ch.name,
                                   size=(z - ch.mu) * ch.resolution, size_counts=z - ch.mu,
                                   normal=ch.mu * ch.resolution)
                new.append(ev)
                ch.mu = ch.sigma = math.nan  # learn the new level, then watch again
                ch.learn_from = t_end_s
                ch.g = 0.0
                self.statistic[i] = 0.0
        self.events.extend(new)
        return new
