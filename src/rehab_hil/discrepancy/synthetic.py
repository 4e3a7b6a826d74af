"""Recordings with a known hidden effect, for tests and the benchmark.

The data come from the plant model WITH the effect, driven open loop by a random multisine
with rests, and made realistic: a small mismatch of an unrelated nominal parameter, Gaussian
noise on analog channels (encoder angles are already quantised by the model's encoder part),
and a logger sample rate different from the model step (sample-and-hold of the model samples).
The excitation is the plant's own (``Plant.excitation``). It reuses the workflow's compiled
augmented system, so it costs no extra compilation.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import numpy as np

from rehab_hil.discrepancy.replay import Replay
from rehab_hil.interchange import Recording
from rehab_hil.plants.registry import Plant

__all__ = ["hidden_effect_recording", "step_records"]


def hidden_effect_recording(spec: type[Plant], cfg: Any, effects: Mapping[str, Mapping[str, float]],
                            duration_s: float = 12.0, rate_hz: float = 800.0, seed: int = 0,
                            noise_scale: float = 1.0, mismatch: bool = True,
                            replay: Replay | None = None) -> Recording:
    """A recording of the plant with ``effects`` ({name: params}) hidden in it.

    ``replay`` (any Replay of this plant and config) lends its compiled system."""
    plan = spec.excitation
    if plan is None:
        raise ValueError(f"plant {spec.name!r} declares no excitation for synthetic records")
    rng = np.random.default_rng(seed)
    step_s = spec.step(cfg)[0]
    n = round(duration_s / step_s)
    t = np.arange(n) * step_s
    u = plan.inputs(t, rng)
    if replay is None or replay.spec.name != spec.name:
        dummy = {**u, **{c: np.zeros(n) for c in spec.outputs}}
        replay = Replay.build(spec, cfg, Recording(t, dummy))
    P = replay.with_effects(replay.nominal_params(), effects)[:replay.n_diagram_params]
    if mismatch:
        name, factor = plan.mismatch
        P[replay.system.diagram.param_index(name)] *= factor
    res = replay.system.simulate(n, {k: v for k, v in u.items() if k in replay.system.input_names},
                                 outputs=list(spec.outputs), params=P)
    tm = np.arange(0.0, t[-1], 1.0 / rate_hz)
    idx = np.minimum(np.floor(tm / step_s + 1e-9).astype(np.int64), n - 1)
    signals = {k: v[idx] for k, v in u.items()}
    for c in spec.outputs:
        sd = plan.noise.get(c, 0.0) * noise_scale
        signals[c] = res.signals[c][idx] + (rng.normal(0.0, sd, tm.size) if sd > 0 else 0.0)
    return Recording(tm, signals)


def step_records(spec: type[Plant], cfg: Any, effects: Mapping[str, Mapping[str, float]],
                 directions: tuple[int, ...] = (1, -1, 1, -1), duration_s: float = 20.0, hold_s: float = 2.0,
                 levels: tuple[float, float] = (0.04, 0.09), noise: float = 0.01, seed: int = 0,
                 scale_params: Mapping[str, float] | None = None, replay: Replay | None = None) -> list[Recording]:
    """Open-loop drive-step records, one direction of motion each (a servo's identification runs:
    steps of the first input, each ``hold_s`` long, between ``levels`` of the drive's full scale and
    rests at zero, all of sign ``directions[i]``), with ``effects`` hidden, diagram parameters scaled
    by ``scale_params`` ({diagram parameter: factor}), and Gaussian noise of std ``noise`` on every
    output. Each record starts at rest."""
    rng = np.random.default_rng(seed)
    step_s = spec.step(cfg)[0]
    n = round(duration_s / step_s)
    t = np.arange(n) * step_s
    name = spec.inputs[0]
    full = spec.ports(cfg).actuators[0].duty_scale
    if replay is None or replay.spec.name != spec.name:
        dummy = {name: np.linspace(0.0, 1.0, n), **{c: np.zeros(n) for c in spec.outputs}}
        replay = Replay.build(spec, cfg, Recording(t, dummy))
    P = replay.with_effects(replay.nominal_params(), effects)[:replay.n_diagram_params]
    for key, factor in (scale_params or {}).items():
        P[replay.system.diagram.param_index(key)] *= factor
    out = []
    for sign in directions:
        k = np.floor(t / hold_s).astype(int)
        amp = rng.uniform(*levels, size=k.max() + 1) * full
        u = np.where(k % 2 == 1, sign * amp[k], 0.0)
        res = replay.system.simulate(n, {name: u}, outputs=[c for c in spec.outputs
                                                            if c in replay.system.diagram.signal_names], params=P)
        signals = {name: u, **{c: v + rng.normal(0.0, noise, n) for c, v in res.signals.items()}}
        out.append(Recording(t.copy(), signals))
    return out
