"""Binding a recording to the model (``Replay.build``): the plant's diagram as a replay runs it, and
how each measured channel's residual is scaled and weighed.

The diagram carries every applicable library effect, attached disabled under ``CANDIDATE_PREFIX``
(fitting an effect is then an edit of one compiled system's parameter vector, never a recompile), and,
for a record of a closed loop, the recorded controller driving the plant from the reference. A
channel's residual is divided by its spread (no finer than the ADC count that read it) and weighs
less in the fits when its noise floor is a large part of that spread (``channel_weights``).
"""

from __future__ import annotations

from typing import Any, NamedTuple

import numpy as np

from rehab_hil.control.cascade import loop_parts
from rehab_hil.discrepancy.closed_loop import describe_loop, recorded_loop
from rehab_hil.discrepancy.verdict import noise_floor
from rehab_hil.effects import Effect, applicable, attach
from rehab_hil.interchange import Recording
from rehab_hil.models.ports import Ports
from rehab_hil.models.system import CompiledSystem, Diagram
from rehab_hil.plants.registry import Plant, compose

__all__ = ["ADC_FULL_SCALE_COUNTS", "CANDIDATE_PREFIX", "NOISY_SPREAD", "Augmented", "augmented", "channel_weights",
           "on_adc_grid"]

CANDIDATE_PREFIX = "candidate"
ADC_FULL_SCALE_COUNTS = 1023  # the Uno's 10-bit ADC (docs/protocol.md)
NOISY_SPREAD = 10.0  # a channel whose spread is under this many noise floors weighs less in the fits


class Augmented(NamedTuple):
    """The plant's augmented diagram, compiled, and what a replay reads from the record for it."""

    ports: Ports
    candidates: list[Effect]  # the applicable library effects, attached disabled
    system: CompiledSystem
    step_s: float  # the model's fixed step
    signals: dict[str, np.ndarray]  # the record's columns (a disturbance it lacks: zeros)
    channels: list[str]  # the output channels compared (with a replayed loop, its effort too)
    loop: str  # the closed-loop replay used (the recorded controller), "" when the effort is replayed


def augmented(spec: type[Plant], cfg: Any, rec: Recording, channels: list[str], closed_loop: bool) -> Augmented:
    """The plant's diagram with every applicable effect attached, disabled; with ``closed_loop`` and a
    config that declares the ``[recorded_controller]`` whose reference and effort the record carries,
    the controller's parts drive the plant input and the recorded effort joins ``channels``
    (``closed_loop.py``)."""
    step_s, substeps = spec.step(cfg)
    ports = spec.ports(cfg)
    candidates = applicable(ports)
    parts = attach(spec.name, ports, step_s, compose(spec, cfg), [(e.name, e.disabled()) for e in candidates],
                   prefix=CANDIDATE_PREFIX)
    signals = dict(rec.signals)
    ext, sums, loop_text = spec.external_inputs(cfg), ports.sums, ""
    loop = recorded_loop(cfg, rec) if closed_loop else None
    if loop is not None:
        for d in loop.disturbances:  # a record without the disturbance had none
            signals.setdefault(d, np.zeros(rec.t.size))
        parts = [*parts, *loop_parts(loop, float(signals[loop.feedback][0]))]
        ext, sums = (*ext, loop.reference, *loop.disturbances), (*sums, loop.effort)
        channels = [*channels, loop.effort]
        loop_text = describe_loop(loop)
    system = Diagram(parts, inputs=ext, sums=sums).compile(step_s, substeps)
    return Augmented(ports, candidates, system, step_s, signals, channels, loop_text)


def channel_weights(ports: Ports, measured: dict[str, np.ndarray], channels: list[str],
                    rig: bool) -> tuple[np.ndarray, dict[str, tuple[float, float, float]], np.ndarray]:
    """Per channel: the scale its residual is divided by, the ADC that read it (``Replay.adc_range``:
    a rig recording's, or one whose values lie on that ADC's grid) and its fit weight.

    The scale is the channel's spread, no finer than one ADC count. The weight is 1, or less for a
    channel whose noise floor is more than 1/NOISY_SPREAD of its spread (the residual is divided by
    ten noise floors instead). A force of a few ADC counts with a count's scatter would otherwise weigh
    as much as an encoder angle 300 times sharper: a hidden 15 % Flexiforce gain bent a fitted driver
    dead zone 4 % (an independent SMA record). Weighing every channel by its noise alone silences a
    motor current with 0.01 A noise, which tells a 13 ms delay from a larger rotor inertia."""
    scale = np.array([max(float(np.std(measured[c])), 1e-9) for c in channels])
    adc = {m.signal: (m.offset_counts, m.counts_per_unit, float(ADC_FULL_SCALE_COUNTS)) for m in ports.measured
           if m.sensor == "adc" and m.signal in channels and m.counts_per_unit > 0
           and (rig or on_adc_grid(measured[m.signal], m.offset_counts, m.counts_per_unit))}
    for k, c in enumerate(channels):  # a channel resolved in fewer counts than its spread weighs less
        if c in adc:
            scale[k] = max(scale[k], 1.0 / adc[c][1])
    weight = scale / np.maximum(scale, NOISY_SPREAD * np.array([noise_floor(measured[c]) for c in channels]))
    return scale, adc, weight


def on_adc_grid(y: np.ndarray, offset_counts: float, counts_per_unit: float,
                full_counts: float = float(ADC_FULL_SCALE_COUNTS)) -> bool:
    """Was ``y`` read through this ADC calibration? Every value a whole count within the converter's
    range: a lab's own logger writes a CSV without the rig flag, and its force column still shows
    neither a negative force nor steps finer than a count."""
    c = offset_counts + counts_per_unit * np.asarray(y, float)
    return bool(c.size and np.all(np.abs(c - np.round(c)) < 1e-3) and c.min() > -1e-3 and c.max() < full_counts + 1e-3)
