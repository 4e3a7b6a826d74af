"""Recordings with a known hidden effect, for tests and the benchmark.

The data come from the plant model WITH the effect, driven open loop by a random multisine
with rests, and made realistic: a small mismatch of an unrelated nominal parameter, Gaussian
noise on analog channels (encoder angles are already quantised by the model's encoder part),
and a logger sample rate different from the model step (sample-and-hold of the model samples).
It reuses the workflow's compiled augmented system, so it costs no extra compilation.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np

from rehab_hil.discrepancy.replay import Replay
from rehab_hil.interchange import Recording
from rehab_hil.plants.base import PlantSpec

__all__ = ["EXCITATION", "Plan", "hidden_effect_recording"]


def _multisine(t: np.ndarray, rng: np.random.Generator, amplitude: float, freqs_hz: tuple[float, ...],
               rest_share: float) -> np.ndarray:
    """Sum of sines with random phases, switched off during random rests (stick, cool down)."""
    u = sum(np.sin(2 * np.pi * f * t + rng.uniform(0, 2 * np.pi)) for f in freqs_hz)
    u = amplitude * np.asarray(u) / len(freqs_hz) * 1.6
    gate = np.sin(2 * np.pi * 0.11 * t + rng.uniform(0, 2 * np.pi)) > (2 * rest_share - 1)
    return u * gate if rest_share > 0 else u


@dataclass(frozen=True)
class Plan:
    """How to excite a plant and which unrelated parameter to mistune."""

    inputs: Callable[[np.ndarray, np.random.Generator], dict[str, np.ndarray]]
    mismatch: tuple[str, float]  # qualified parameter, factor
    noise: Mapping[str, float]  # channel -> standard deviation (its unit)


def _levels(t: np.ndarray, rng: np.random.Generator, levels: tuple[float, ...], hold_s: tuple[float, float],
            off_share: float) -> np.ndarray:
    """Piecewise-constant random levels (heating pulses and cooling rests of random length)."""
    out = np.zeros_like(t)
    start = 0.0
    while start < t[-1]:
        hold = rng.uniform(*hold_s)
        level = 0.0 if rng.random() < off_share else float(rng.choice(levels))
        out[(t >= start) & (t < start + hold)] = level
        start += hold
    return out


EXCITATION: dict[str, Plan] = {
    "sma_exoskeleton": Plan(
        inputs=lambda t, rng: {"pwm_duty": _levels(t, rng, (0.4, 0.6, 0.8, 1.0), (1.5, 4.0), 0.4),
                               "supply_voltage_v": np.full_like(t, 32.0)},
        mismatch=("damping_dip.damping_nm_s_per_rad", 1.1),
        noise={"theta_mcp_deg": 0.1, "theta_pip_deg": 0.1, "theta_dip_deg": 0.1, "contact_force_n": 0.02,
               "sma_tension_n": 0.05, "sma_temperature_c": 0.3},
    ),
    "tcp_finger": Plan(
        inputs=lambda t, rng: {"power_w": _levels(t, rng, (34.0, 40.0, 47.0), (1.0, 4.0), 0.5),
                               "measured_force_n": np.zeros_like(t)},
        mismatch=("damping_dip.damping_nm_s_per_rad", 1.1),
        noise={"tcp_temperature_c": 0.2, "tcp_force_n": 0.01, "theta_mcp_deg": 0.1, "theta_pip_deg": 0.1,
               "theta_dip_deg": 0.1},
    ),
    "finger_extensor": Plan(
        inputs=lambda t, rng: {"motor_voltage_v": _multisine(t, rng, 2.5, (0.35, 0.8, 1.7), 0.2),
                               "patient_torque_nm": np.zeros_like(t)},
        mismatch=("iris.inertia_kg_m2", 1.05),
        noise={"motor_current_a": 0.01},
    ),
}


def hidden_effect_recording(spec: PlantSpec, cfg: Any, effects: Mapping[str, Mapping[str, float]],
                            duration_s: float = 12.0, rate_hz: float = 800.0, seed: int = 0,
                            noise_scale: float = 1.0, mismatch: bool = True,
                            replay: Replay | None = None) -> Recording:
    """A recording of the plant with ``effects`` ({name: params}) hidden in it.

    ``replay`` (any Replay of this plant and config) lends its compiled system."""
    plan = EXCITATION[spec.name]
    rng = np.random.default_rng(seed)
    step_s = spec.step(cfg)[0]
    n = round(duration_s / step_s)
    t = np.arange(n) * step_s
    u = plan.inputs(t, rng)
    if replay is None or replay.spec.name != spec.name:
        dummy = {**u, **{c: np.zeros(n) for c in spec.outputs}}
        replay = Replay.build(spec, cfg, Recording(t, dummy))
    P = replay.with_effects(replay.nominal_params(), effects)
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
