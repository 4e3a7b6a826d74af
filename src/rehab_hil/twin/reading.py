"""``RigReading``: how the rig reads the twin model's channels, so the model is compared as measured.

An encoder reads whole counts (``smooth``: the angle before its quantisation, in degrees, for an
estimate whose finite differences need a prediction that moves with a parameter); an ADC reads within
its converter's range (a 10-bit ADC shows no negative force), never rounded (fits need a slope).
Each channel's resolution is one count in its unit: within half of it the truth may lie anywhere.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

import numpy as np

from rehab_hil.discrepancy.replay import ADC_FULL_SCALE_COUNTS
from rehab_hil.interfaces import DeviceBinding
from rehab_hil.models.sensors import QuadratureEncoder

__all__ = ["RigReading"]

RAD_TO_DEG = 180.0 / math.pi


class RigReading:
    """The rig's reading of ``channels`` of a diagram of ``parts``: ``signals`` are the model signals
    read for them (an encoder's angle in rad when ``smooth``), ``resolution`` a count of each."""

    def __init__(self, binding: DeviceBinding, channels: Sequence[str], parts: Sequence[Any], smooth: bool) -> None:
        self.binding = binding
        # channels read before their encoder's quantisation, in rad (-> deg in ``sensed``)
        self.signals = [(_encoder_input(parts, c) if smooth else None) or c for c in channels]
        self._unquantised = [j for j, (r, c) in enumerate(zip(self.signals, channels, strict=True)) if r != c]
        self.resolution = np.array([self._resolution(c) for c in channels])
        # the ADC a channel is read through: the model's value is clipped to the converter's range as
        # the rig's reading is (a 10-bit ADC shows no negative force), never rounded (fits need a slope)
        self._adc = [(j, a.offset_counts, a.counts_per_unit) for j, c in enumerate(channels)
                     for a in binding.adc if a.signal == c]

    def _resolution(self, channel: str) -> float:
        """The smallest change a channel shows: an encoder count in degrees, an ADC count in its unit."""
        b = self.binding
        if channel == b.angle_output:
            return 360.0 / b.encoder_counts_per_rev
        ch = next(a for a in b.adc if a.signal == channel)
        return 1.0 / abs(ch.counts_per_unit)

    def sensed(self, Y: np.ndarray) -> np.ndarray:
        """Model outputs through the rig's ADC range (in place; see ``_adc``)."""
        for j in self._unquantised:
            Y[:, j] *= RAD_TO_DEG
        for j, offset, per_unit in self._adc:
            c = np.clip(offset + per_unit * Y[:, j], 0.0, ADC_FULL_SCALE_COUNTS)
            Y[:, j] = (c - offset) / per_unit
        return Y

    def beyond_resolution(self, err: np.ndarray) -> np.ndarray:
        """The part of an error a sensor can vouch for: within half a count of the reading the
        truth may lie anywhere, and anchoring a slow state (a coil's heat behind a force) on that
        rounding walks it away from a model that was right."""
        e = np.nan_to_num(err)
        return np.sign(e) * np.maximum(np.abs(e) - 0.5 * self.resolution, 0.0)


def _encoder_input(parts: Sequence[Any], channel: str) -> str | None:
    """The angle signal (rad) a quadrature encoder part turns into ``channel`` (deg), if one does,
    through a single unit-gain connection."""
    for p in parts:
        if isinstance(p, QuadratureEncoder) and channel in p.signal_names:
            terms = p.connections["angle_rad"]
            if len(terms) == 1 and terms[0][1] == 1.0:
                return terms[0][0]
    return None
