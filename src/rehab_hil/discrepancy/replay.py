"""Replay: the model driven by the measured inputs, compared on every measured output channel.

The measured inputs are resampled (linear interpolation) onto the model's fixed step; model
outputs are interpolated back onto the measured time stamps, so a recording at any rate can be
compared. The diagram carries every applicable library effect, disabled, so fitting an effect is
an edit of the parameter vector of one compiled system (``with_effects``), never a recompile.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from rehab_hil.effects import Effect, applicable, attach
from rehab_hil.interchange import CsvError, Recording
from rehab_hil.models.ports import Ports
from rehab_hil.models.system import CompiledSystem, Diagram
from rehab_hil.plants.base import Plant, compose, plants

__all__ = ["CANDIDATE_PREFIX", "MIN_DURATION_S", "MIN_SAMPLES", "Replay", "check_recording"]

CANDIDATE_PREFIX = "candidate"
MIN_DURATION_S = 2.0  # shorter records cannot be split into a fit part and a held-out part
MIN_SAMPLES = 100


def check_recording(spec: type[Plant], rec: Recording, path: str | Path) -> list[str]:
    """Check a recording can be replayed on ``spec``; returns the output channels present.

    Errors name the file: missing input columns (and which plant the file looks like), no output
    column, too short, inputs that never change."""
    missing = [n for n in spec.inputs if n not in rec.signals and n not in spec.optional_inputs]
    if missing:
        looks = [p.name for p in plants().values() if p.name != spec.name and all(i in rec.signals for i in p.inputs)]
        hint = f"; the columns look like a {looks[0]!r} recording, the config is {spec.name!r}" if looks else ""
        raise CsvError(path, 1, f"missing input columns {missing} of plant {spec.name!r} "
                                f"(have {sorted(rec.signals)}){hint}")
    channels = [o for o in spec.outputs if o in rec.signals]
    if not channels:
        raise CsvError(path, 1, f"no output column of plant {spec.name!r} to compare; "
                                f"expected any of {list(spec.outputs)}")
    duration = float(rec.t[-1] - rec.t[0])
    if rec.t.size < MIN_SAMPLES or duration < MIN_DURATION_S:
        raise CsvError(path, None, f"too short: {rec.t.size} rows over {duration:.3f} s; the workflow needs at "
                                   f"least {MIN_SAMPLES} rows and {MIN_DURATION_S} s (a fit part and a held-out part)")
    if all(np.ptp(rec.signals[n]) == 0.0 for n in spec.inputs if n in rec.signals):
        raise CsvError(path, None, f"the input columns {list(spec.inputs)} are constant: the recording does not "
                                   "excite the plant, so no effect can be identified")
    return channels


@dataclass
class Replay:
    """Measured data bound to the plant's augmented compiled system."""

    spec: type[Plant]
    cfg: Any
    ports: Ports
    system: CompiledSystem
    candidates: list[Effect]
    t: np.ndarray  # measured time stamps, from 0
    measured: dict[str, np.ndarray]
    channels: list[str]
    inputs: dict[str, np.ndarray]  # on the model grid
    scale: np.ndarray  # per channel: residuals are divided by it (dimensionless, comparable)
    _idx: np.ndarray
    _w: np.ndarray

    @classmethod
    def build(cls, spec: type[Plant], cfg: Any, rec: Recording, path: str | Path = "<data>") -> Replay:
        channels = check_recording(spec, rec, path)
        step_s, substeps = spec.step(cfg)
        ports = spec.ports(cfg)
        candidates = applicable(ports)
        parts = attach(spec.name, ports, step_s, compose(spec, cfg), [(e.name, e.disabled()) for e in candidates],
                       prefix=CANDIDATE_PREFIX)
        system = Diagram(parts, inputs=spec.external_inputs(cfg)).compile(step_s, substeps)
        t = rec.t - rec.t[0]
        n = int(np.floor(t[-1] / step_s + 1e-9)) + 2
        grid = np.arange(n) * step_s
        inputs = {k: np.interp(grid, t, rec.signals[k]) for k in spec.inputs
                  if k in system.input_names and k in rec.signals}
        pos = t / step_s
        idx = np.minimum(np.floor(pos).astype(np.int64), n - 2)
        measured = {c: np.asarray(rec.signals[c], float) for c in channels}
        scale = np.array([max(float(np.std(measured[c])), 1e-9) for c in channels])
        return cls(spec, cfg, ports, system, candidates, t, measured, channels, inputs, scale, idx, pos - idx)

    @property
    def n_steps(self) -> int:
        return len(next(iter(self.inputs.values()))) if self.inputs else int(self._idx[-1]) + 2

    def index(self, effect: str, param: str) -> int:
        """Position of a candidate effect's parameter in the parameter vector."""
        return self.system.diagram.param_index(f"{CANDIDATE_PREFIX}_{effect}.{param}")

    def with_effects(self, base: np.ndarray, values: Mapping[str, Mapping[str, float]]) -> np.ndarray:
        """A copy of ``base`` with the given candidate effects' parameters set."""
        P = np.array(base, float)
        for eff, params in values.items():
            for k, v in params.items():
                P[self.index(eff, k)] = v
        return P

    def steps_for(self, n_meas: int) -> int:
        """Model steps needed to cover the first ``n_meas`` measured samples."""
        return int(self._idx[n_meas - 1]) + 2

    def simulate(self, P: np.ndarray, n_meas: int | None = None) -> dict[str, np.ndarray]:
        """Model outputs at the first ``n_meas`` measured time stamps (all by default)."""
        n_meas = self.t.size if n_meas is None else n_meas
        n = self.steps_for(n_meas)
        res = self.system.simulate(n, {k: v[:n] for k, v in self.inputs.items()}, outputs=self.channels, params=P)
        i, w = self._idx[:n_meas], self._w[:n_meas]
        return {c: res.signals[c][i] * (1.0 - w) + res.signals[c][i + 1] * w for c in self.channels}

    def residual(self, sim: Mapping[str, np.ndarray], sl: slice = slice(None)) -> np.ndarray:
        """Scaled residual (model - measured) / scale, shape (channels, samples)."""
        return np.vstack([(sim[c][sl] - self.measured[c][sl]) / s
                          for c, s in zip(self.channels, self.scale, strict=True)])

    def nominal_params(self) -> np.ndarray:
        return self.system.params.copy()


def channel_metrics(measured: Sequence[float] | np.ndarray, model: Sequence[float] | np.ndarray) -> dict[str, float]:
    """RMSE, MAE and largest absolute error of one channel, in its own unit."""
    from rehab_hil import metrics

    m, y = np.asarray(measured, float), np.asarray(model, float)
    return {"rmse": metrics.rmse(m, y), "mae": metrics.mae(m, y), "max_abs_error": metrics.max_abs_error(m, y)}
