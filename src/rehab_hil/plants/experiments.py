"""What a plant is run and fitted with: scenarios (closed- or open-loop experiments on its model),
the excitation for identification, the nominal parameters the discrepancy workflow may find off,
and two excitation signals (a gated multisine, random levels)."""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from rehab_hil.models.system import Part, SimulationResult

__all__ = ["Excitation", "FitParameter", "Scenario", "multisine", "random_levels"]


@dataclass
class Scenario:
    """A closed- or open-loop experiment: extra parts (reference, controller), external input
    arrays per step, the signals its parts sum onto beyond the plant's (a feedforward plus a
    feedback effort), and a function that turns the result into metrics."""

    name: str
    n_steps: int
    parts: list[Part] = field(default_factory=list)
    inputs: Mapping[str, float | np.ndarray] = field(default_factory=dict)
    extra_outputs: tuple[str, ...] = ()
    metrics: Callable[[SimulationResult], dict[str, float]] | None = None
    sums: tuple[str, ...] = ()


@dataclass(frozen=True)
class Excitation:
    """How to excite a plant for identification (synthetic records, the discrepancy benchmark):
    input arrays for time stamps, one nominal parameter to mistune, and sensor noise per channel."""

    inputs: Callable[[np.ndarray, np.random.Generator], dict[str, np.ndarray]]
    mismatch: tuple[str, float]  # qualified parameter, factor
    noise: Mapping[str, float]  # channel -> standard deviation (its unit)


@dataclass(frozen=True)
class FitParameter:
    """A nominal parameter the discrepancy workflow may find off (docs/discrepancy.md): its config
    key, the diagram parameters (``"part.param"``) and external inputs scaled with it, and the
    corrected config value for a factor (default: the config value times the factor)."""

    config_key: str  # dotted key in the plant's TOML, e.g. "motor.kt_nm_per_a"
    diagram: tuple[str, ...] = ()
    inputs: tuple[str, ...] = ()
    to_config: Callable[[Any, float], float] | None = None
    # a physically coupled group (a weaker magnet lowers k_t and k_v together): the other config keys
    # corrected by the same factor, and the candidate's name ("motor flux (k_t, k_v)"); default: the key
    also: tuple[str, ...] = ()
    label: str = ""

    @property
    def name(self) -> str:
        return self.label or self.config_key


def multisine(t: np.ndarray, rng: np.random.Generator, amplitude: float, freqs_hz: tuple[float, ...],
               rest_share: float) -> np.ndarray:
    """Sum of sines with random phases, switched off during random rests (stick, cool down)."""
    u = sum(np.sin(2 * np.pi * f * t + rng.uniform(0, 2 * np.pi)) for f in freqs_hz)
    u = amplitude * np.asarray(u) / len(freqs_hz) * 1.6
    gate = np.sin(2 * np.pi * 0.11 * t + rng.uniform(0, 2 * np.pi)) > (2 * rest_share - 1)
    return u * gate if rest_share > 0 else u


def random_levels(t: np.ndarray, rng: np.random.Generator, levels: tuple[float, ...], hold_s: tuple[float, float],
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
