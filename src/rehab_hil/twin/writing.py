"""What the live twin writes of each block it processed: the rows of ``twin.csv`` and the prediction
messages for its listeners (``twin.outputs``).

``twin.csv``: per sample the time, each channel's prediction, residual and CUSUM statistic, and each
estimated patient parameter (``patient_column``). A prediction message every ``PREDICTION_EVERY``
samples (100 Hz at 1 kHz: plots, not data) carries each channel's measured, predicted and residual
value and CUSUM statistic, the estimates and the plant-independent angle fields
(``outputs.GENERIC_TWIN_FIELDS``). Writing gives the interpreter back every ``YIELD_EVERY`` rows: the
twin's thread must not hold the loop's for long.
"""

from __future__ import annotations

import os
import time
from collections.abc import Iterator, Sequence
from pathlib import Path
from typing import Any

import numpy as np

__all__ = ["PREDICTION_EVERY", "YIELD_EVERY", "TwinCsv", "patient_column", "prediction_messages"]

PREDICTION_EVERY = 10  # one prediction message per this many samples (100 Hz at 1 kHz): plots, not data
YIELD_EVERY = 32  # records taken between two releases of the interpreter


def patient_column(name: str) -> str:
    """The recorded column of an estimated parameter (``part.param`` -> ``patient_part_param``)."""
    return "patient_" + name.replace(".", "_")


class TwinCsv:
    """``twin.csv`` in ``out_dir`` for ``channels`` and the estimated parameters ``estimates``, its header
    written at once."""

    def __init__(self, out_dir: str | Path, channels: Sequence[str], estimates: Sequence[str]) -> None:
        self.path = Path(out_dir) / "twin.csv"
        self._fd = os.open(self.path, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o644)
        cols = ["time_s", *(f"{c}_predicted" for c in channels), *(f"{c}_residual" for c in channels),
                *(f"{c}_cusum_counts" for c in channels), *(patient_column(n) for n in estimates)]
        os.write(self._fd, (",".join(cols) + "\n").encode())

    def write(self, block: Any, g: np.ndarray, est: np.ndarray) -> None:
        """The rows of ``block`` with the CUSUM statistics ``g`` and the estimates' values ``est`` now."""
        cols = np.column_stack([block.t_s, block.predicted, block.residual,
                                np.broadcast_to(g, (block.t_s.size, g.size)),
                                np.broadcast_to(est, (block.t_s.size, est.size))])
        lines = []
        for k, row in enumerate(cols):
            lines.append(",".join(f"{v:.8g}" for v in row))
            if k % YIELD_EVERY == YIELD_EVERY - 1:
                time.sleep(0)
        os.write(self._fd, ("\n".join(lines) + "\n").encode())

    def close(self) -> None:
        """Close the file (idempotent)."""
        if self._fd >= 0:
            os.close(self._fd)
            self._fd = -1


def prediction_messages(block: Any, channels: Sequence[str], g: np.ndarray, estimates: Sequence[Any],
                        angle: int) -> Iterator[dict[str, float]]:
    """The prediction messages of ``block``, one per ``PREDICTION_EVERY`` samples: per channel measured,
    predicted, residual and the CUSUM statistic ``g``; each estimate's value; the angle channel's
    (index ``angle``, -1: none) generic fields and the largest statistic."""
    for k in range(0, block.t_s.size, PREDICTION_EVERY):
        msg = {"time_s": float(block.t_s[k])}
        for j, c in enumerate(channels):
            msg[f"{c}_measured"] = float(block.measured[k, j])
            msg[f"{c}_predicted"] = float(block.predicted[k, j])
            msg[f"{c}_residual"] = float(block.residual[k, j])
            msg[f"{c}_cusum_counts"] = float(g[j])
        for e in estimates:
            msg[patient_column(e.name)] = e.value
        if angle >= 0:  # outputs.GENERIC_TWIN_FIELDS
            msg["angle_measured_deg"] = float(block.measured[k, angle])
            msg["angle_predicted_deg"] = float(block.predicted[k, angle])
            msg["angle_residual_deg"] = float(block.residual[k, angle])
        msg["cusum_max_counts"] = float(g.max())
        yield msg
