"""Replay: the model driven by the measured inputs, compared on every measured output channel.

The measured inputs are resampled (linear interpolation) onto the model's fixed step; model
outputs are interpolated back onto the measured time stamps, so a recording at any rate can be
compared. The diagram carries every applicable library effect, disabled, so fitting an effect is
an edit of the parameter vector of one compiled system (``with_effects``), never a recompile
(binding.py builds it, and scales and weighs each channel).
"""

from __future__ import annotations

from collections import OrderedDict
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from rehab_hil import metrics
from rehab_hil.discrepancy.binding import (
    ADC_FULL_SCALE_COUNTS,
    CANDIDATE_PREFIX,
    NOISY_SPREAD,
    augmented,
    channel_weights,
    on_adc_grid,
)
from rehab_hil.effects import Effect
from rehab_hil.interchange import CsvError, Recording
from rehab_hil.models.ports import Ports
from rehab_hil.models.system import CompiledSystem
from rehab_hil.plants.registry import Plant, plants

__all__ = ["ADC_FULL_SCALE_COUNTS", "CANDIDATE_PREFIX", "MIN_DURATION_S", "MIN_SAMPLES", "NOISY_SPREAD", "Replay",
           "check_recording", "on_adc_grid"]

MIN_DURATION_S = 2.0  # shorter records cannot be split into a fit part and a held-out part
MIN_SAMPLES = 100
SIM_CACHE = 64  # replays kept for a repeated request (``Replay.simulate_grid``) ...
SIM_CACHE_BYTES = 32 << 20  # ... and at most this many bytes of them


def check_recording(spec: type[Plant], rec: Recording, path: str | Path, cfg: Any = None) -> list[str]:
    """Check a recording can be replayed on ``spec`` (under ``cfg``: the input columns it names, e.g. a
    drive commanded in torque); returns the output channels present.

    Errors name the file: missing input columns (and which plant the file looks like), no output
    column, too short, inputs that never change."""
    inputs = spec.input_signals(cfg) if cfg is not None else spec.inputs
    missing = [n for n in inputs if n not in rec.signals and (n not in spec.optional_inputs or cfg is not None)]
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
    if all(np.ptp(rec.signals[n]) == 0.0 for n in inputs if n in rec.signals):
        raise CsvError(path, None, f"the input columns {list(inputs)} are constant: the recording does not "
                                   "excite the plant, so no effect can be identified")
    return channels


class RunCache:
    """The last runs of a replay (``Replay.simulate_grid``), newest last: at most ``SIM_CACHE`` of them
    and ``SIM_CACHE_BYTES``. Each is kept and handed out as a copy, so no caller can change it."""

    def __init__(self) -> None:
        self._runs: OrderedDict[tuple[Any, ...], np.ndarray] = OrderedDict()

    def get(self, key: tuple[Any, ...]) -> np.ndarray | None:
        """A copy of the run kept under ``key`` (now the newest), or None."""
        hit = self._runs.get(key)
        if hit is None:
            return None
        self._runs.move_to_end(key)
        return hit.copy()

    def put(self, key: tuple[Any, ...], Y: np.ndarray) -> None:
        """Keep a copy of ``Y``; the oldest runs go beyond the count or the bytes allowed."""
        runs = self._runs
        runs[key] = Y.copy()
        while runs and (len(runs) > SIM_CACHE or sum(v.nbytes for v in runs.values()) > SIM_CACHE_BYTES):
            runs.popitem(last=False)


@dataclass
class Replay:
    """Measured data bound to the plant's augmented compiled system.

    A parameter vector here is the diagram's (``Diagram.param_index``) followed by one scale per
    external input (1 nominally): a fit parameter may scale an input the record does not measure
    (a supply voltage taken from the config). ``x0``/``xd0`` is the state at the record's start
    (``initial_state``); ``mode`` is ``"open"`` (simulation error: one run over the record) or
    ``"shooting"`` (segments of ``segment_steps`` re-anchored to the measured state, ``shoot``; when
    to use which is ``shooting.choose_mode``)."""

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
    U: np.ndarray = field(default_factory=lambda: np.zeros((0, 0)))  # external inputs, model grid x inputs
    measured_grid: np.ndarray = field(default_factory=lambda: np.zeros((0, 0)))  # channels x model steps
    x0: np.ndarray = field(default_factory=lambda: np.zeros(0))
    xd0: np.ndarray = field(default_factory=lambda: np.zeros(0))
    mode: str = "open"
    segment_steps: int = 0
    anchor_gain: np.ndarray | None = None  # states x channels: scaled output error -> state correction
    fit_start: int = 0  # first measured sample the fits use: the start state's memory is over (initial_state)
    # channel -> (offset_counts, counts_per_unit, full-scale counts) of the rig's ADC that measured it:
    # on a rig recording the model is read through the same converter (whole counts, 0..1023: a
    # 10-bit ADC shows neither a negative force nor steps finer than a count), so its quantisation
    # and clipping are not mistaken for a missing effect
    adc_range: dict[str, tuple[float, float, float]] = field(default_factory=dict)
    # per channel, what the fits and the BIC weigh the scaled residual by: 1, or less for a noisy channel
    # (``binding.channel_weights`` says how and why)
    fit_weight: np.ndarray = field(default_factory=lambda: np.ones(0))
    loop: str = ""  # the closed-loop replay used (the recorded controller), "" when the effort was replayed
    start: str = "estimate"  # "estimate", "rest" or "auto" (rest when the data show it): ``initial_state``

    @classmethod
    def build(cls, spec: type[Plant], cfg: Any, rec: Recording, path: str | Path = "<data>",
              closed_loop: bool = True) -> Replay:
        """Bind ``rec`` to the plant's augmented diagram. With ``closed_loop`` and a config that declares
        the ``[recorded_controller]`` whose reference and effort the record carries, the loop is replayed
        from the reference: the controller's parts drive the plant input, and the recorded effort is
        compared as an output channel (``closed_loop.py``)."""
        channels = check_recording(spec, rec, path, cfg)
        aug = augmented(spec, cfg, rec, channels, closed_loop)
        system, signals, channels, step_s = aug.system, aug.signals, aug.channels, aug.step_s
        t = rec.t - rec.t[0]
        n = int(np.floor(t[-1] / step_s + 1e-9)) + 2
        grid = np.arange(n) * step_s
        inputs = {k: np.interp(grid, t, signals[k]) for k in system.input_names if k in signals}
        pos = t / step_s
        idx = np.minimum(np.floor(pos).astype(np.int64), n - 2)
        measured = {c: np.asarray(signals[c], float) for c in channels}
        U = system.input_matrix(n, inputs)
        mgrid = np.vstack([np.interp(grid, t, measured[c]) for c in channels])
        scale, adc, weight = channel_weights(aug.ports, measured, channels, rec.rig)
        return cls(spec, cfg, aug.ports, system, aug.candidates, t, measured, channels, inputs, scale, idx, pos - idx,
                   U, mgrid, system.x0.copy(), system.xd0.copy(), adc_range=adc, fit_weight=weight, loop=aug.loop)

    @property
    def n_steps(self) -> int:
        return self.U.shape[0]

    @property
    def n_diagram_params(self) -> int:
        return self.system.params.size

    def input_scale_index(self, name: str) -> int:
        """Position of an input's scale in the parameter vector."""
        return self.n_diagram_params + self.system.input_names.index(name)

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

    def run(self, P: np.ndarray, start: int, n: int, x: np.ndarray, xd: np.ndarray) -> np.ndarray:
        """Channel outputs (steps x channels) of ``n`` model steps from step ``start``; ``x`` and
        ``xd`` are advanced in place to the state after the last step."""
        s = self.system
        npar = self.n_diagram_params
        U = self.U[start:start + n]
        scales = P[npar:]
        if scales.size and np.any(scales != 1.0):
            U = U * scales
        _, Y = s.run_arrays(x, xd, np.ascontiguousarray(U), np.ascontiguousarray(P[:npar]), self._slots(),
                            s.workspace())
        return Y

    def use_segments(self, segment_s: float) -> None:
        """Shoot in segments of ``segment_s`` (rounded to whole model steps, at least one)."""
        self.segment_steps = max(1, round(segment_s / self.system.dt))

    def shoot(self, P: np.ndarray, n: int, x: np.ndarray, xd: np.ndarray) -> np.ndarray:
        """Channel outputs on the model grid (steps x channels) by multiple shooting: segments of
        ``segment_steps``, the state re-anchored through ``anchor_gain`` at each segment's start."""
        K = self.anchor_gain
        assert K is not None
        L = self.segment_steps
        Y = np.empty((n, len(self.channels)))
        a = 0
        while a < n:
            b = min(a + L, n)
            Y[a:b] = self.run(P, a, b - a, x, xd)
            if b < n:
                err = (self.measured_grid[:, b - 1] - Y[b - 1]) / self.scale
                dx = K @ np.nan_to_num(err)
                if np.all(np.isfinite(x)):
                    x += dx
            a = b
        return Y

    def _slots(self) -> np.ndarray:
        if not hasattr(self, "_out_slots"):
            self._out_slots = self.system.out_slots(self.channels)
        return self._out_slots

    def simulate_grid(self, P: np.ndarray, n: int, mode: str | None = None,
                      x0: np.ndarray | None = None, xd0: np.ndarray | None = None) -> np.ndarray:
        """Channel outputs on the model grid (steps x channels), open loop or by shooting.

        The same run asked for again (same parameters, steps, mode, start state and anchoring) is
        answered from a small cache of the last ``SIM_CACHE`` runs (``SIM_CACHE_BYTES`` at most), a copy
        of the same array (``drop_cache`` empties it): the
        workflow scores every candidate of a round from the same base model, and the optimiser's
        first point is often the start it was handed."""
        mode = mode or self.mode
        x = np.array(self.x0 if x0 is None else x0, float)
        xd = np.array(self.xd0 if xd0 is None else xd0, float)
        shooting = not (mode == "open" or self.anchor_gain is None or self.segment_steps <= 0)
        P = np.asarray(P, float)
        key = (n, shooting, P.tobytes(), x.tobytes(), xd.tobytes(),
               (self.segment_steps, np.asarray(self.anchor_gain, float).tobytes()) if shooting else None)
        cache = self.__dict__.setdefault("_sim_cache", RunCache())
        Y = cache.get(key)
        if Y is None:
            Y = self.shoot(P, n, x, xd) if shooting else self.run(P, 0, n, x, xd)
            cache.put(key, Y)
        return Y

    def drop_cache(self) -> None:
        """Forget the cached runs (a finished workflow's replay lives on in its result)."""
        self.__dict__.pop("_sim_cache", None)

    def simulate(self, P: np.ndarray, n_meas: int | None = None, mode: str | None = None,
                 sensed: bool = True) -> dict[str, np.ndarray]:
        """Model outputs at the first ``n_meas`` measured time stamps (all by default), read through
        the rig's ADC (``adc_range``) as the data were: clipped to the converter's range, and with
        ``sensed`` rounded to whole counts. Fits use ``sensed=False``: a rounded output is flat
        between counts and gives a fit no slope, but the clip stays (a model force below zero
        compared with a force ADC's floor is an error no sensor gain or effect should fit: measured
        on an SMA record, it turned a hidden +15 % Flexiforce gain into a fitted -12 %)."""
        n_meas = self.t.size if n_meas is None else n_meas
        out = self._at_samples(self.simulate_grid(P, self.steps_for(n_meas), mode), n_meas)
        for c, (offset, per_unit, full) in self.adc_range.items():
            counts = offset + per_unit * out[c]
            out[c] = (np.clip(np.round(counts) if sensed else counts, 0.0, full) - offset) / per_unit
        return out

    def simulate_from(self, P: np.ndarray, n_meas: int, x0: np.ndarray, xd0: np.ndarray) -> dict[str, np.ndarray]:
        """Open-loop model outputs at the first ``n_meas`` measured time stamps from the start state
        ``x0``/``xd0`` (left unchanged), not read through the ADC: what a start-state fit compares."""
        return self._at_samples(self.simulate_grid(P, self.steps_for(n_meas), "open", x0, xd0), n_meas)

    def _at_samples(self, Y: np.ndarray, n_meas: int) -> dict[str, np.ndarray]:
        """Grid outputs (steps x channels) interpolated onto the first ``n_meas`` measured time stamps."""
        i, w = self._idx[:n_meas], self._w[:n_meas]
        return {c: Y[i, j] * (1.0 - w) + Y[i + 1, j] * w for j, c in enumerate(self.channels)}

    @property
    def kinds(self) -> dict[str, str]:
        """Channel -> what it measures (angle, force, temperature ...; "" when the ports do not say)."""
        return {c: self.ports.measured_kind(c) or "" for c in self.channels}

    def residual(self, sim: Mapping[str, np.ndarray], sl: slice = slice(None), weighted: bool = False) -> np.ndarray:
        """Scaled residual (model - measured) / scale, shape (channels, samples); ``weighted``: times
        ``fit_weight`` (what the fits minimise)."""
        r = np.vstack([(sim[c][sl] - self.measured[c][sl]) / s for c, s in zip(self.channels, self.scale, strict=True)])
        return r * self.fit_weight[:, None] if weighted else r

    def nominal_params(self) -> np.ndarray:
        """The diagram's parameters followed by the input scales (all 1)."""
        return np.concatenate([self.system.params, np.ones(len(self.system.input_names))])


def channel_metrics(measured: Sequence[float] | np.ndarray, model: Sequence[float] | np.ndarray) -> dict[str, float]:
    """RMSE, MAE and largest absolute error of one channel, in its own unit."""
    m, y = np.asarray(measured, float), np.asarray(model, float)
    return {"rmse": metrics.rmse(m, y), "mae": metrics.mae(m, y), "max_abs_error": metrics.max_abs_error(m, y)}
