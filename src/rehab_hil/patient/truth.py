"""``sim_truth.csv``: what the simulated rig really did, written by the simulated device beside the
recording so benches and tests can score what the host estimates. A real rig has no such file.

One row per ``every_s`` of the device's session clock: ``t_s`` then the axis's true angle and velocity,
the heated actuator's true temperature (``sma_temperature_c``, ``tcp_temperature_c``: what the safety
estimates and no rig measures) and a simulated patient's signals (``devices.patient_plant.truth_signals``;
SI units in the names). The session clock restarts at each accepted CONFIGURE (homing's, then the loop's): the
file restarts with it, so it always holds the session the host ran.
"""

from __future__ import annotations

import math
import shutil
import tempfile
from collections.abc import Sequence
from pathlib import Path
from typing import TextIO

import numpy as np

__all__ = ["TRUTH_FILE", "SimTruth", "TruthWriter", "read_truth"]

TRUTH_FILE = "sim_truth.csv"
_FLUSH_ROWS = 100


class TruthWriter:
    """Rows of (session time, values) to a CSV file, one per ``every_s``; flushed every 100 rows
    and on ``close`` (a killed device leaves a readable file missing its last second at most)."""

    def __init__(self, path: str | Path, names: Sequence[str], every_s: float = 0.01) -> None:
        self.path, self.names, self.every_s = Path(path), tuple(names), every_s
        self._f: TextIO | None = open(self.path, "w", encoding="utf-8")
        self._header()
        self._next, self._last, self._rows = 0.0, -math.inf, 0

    def _header(self) -> None:
        assert self._f is not None
        self._f.write(",".join(("t_s", *self.names)) + "\n")

    def __call__(self, t_s: float, values: np.ndarray) -> None:
        f = self._f
        if f is None:
            return
        if t_s < self._last:  # a new session clock (an accepted CONFIGURE): start the file again
            f.seek(0)
            f.truncate()
            self._header()
            self._next = 0.0
        self._last = t_s
        if t_s + 1e-9 < self._next:
            return
        self._next = t_s + self.every_s
        f.write(f"{t_s:.3f}," + ",".join(f"{v:.6g}" for v in values) + "\n")
        self._rows += 1
        if self._rows % _FLUSH_ROWS == 0:
            f.flush()

    def close(self) -> None:
        if self._f is not None:
            self._f.close()
            self._f = None


def read_truth(path: str | Path) -> dict[str, np.ndarray]:
    """The columns of a ``sim_truth.csv`` by name."""
    data = np.genfromtxt(path, delimiter=",", names=True)
    return {n: np.atleast_1d(data[n]) for n in data.dtype.names or ()}


class SimTruth:
    """The host's side: a temporary ``sim_truth.csv`` path for the device, moved into the run
    directory (``run_dir``, once the session made one) after the device has closed it."""

    def __init__(self) -> None:
        self._dir = Path(tempfile.mkdtemp(prefix="rehab-hil-truth-"))
        self.path = self._dir / TRUTH_FILE
        self.run_dir: Path | None = None

    def finish(self) -> None:
        """Into the run directory if there is one; the temporary folder goes either way."""
        try:
            if self.run_dir is not None and self.path.exists():
                shutil.move(str(self.path), str(self.run_dir / TRUTH_FILE))
        finally:
            shutil.rmtree(self._dir, ignore_errors=True)
