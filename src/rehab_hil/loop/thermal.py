"""The safety's actuator temperature in the loop: the plant's thermal model (``plants/thermal.py``) advanced
in device time on the duty the rig applies, the state the controller's observer follows, and the values the
twin may tighten, never loosen.

The supervisor owns it (``loop/supervisor.py``). ``apply`` advances it over the period a command holds,
first over the periods a burst of samples skipped with the duty held then; ``state_at`` brings it to a
sample's time for the controller, whose ceiling so acts on the very estimate the supervisor trips on
(``loop/controllers.py``). ``tighten`` takes a ``ThermalTightening``: values the session's process judged
stricter than those in force (``service/features/safety_thermal.py``: a warmer room, less convection, a
higher supply, each the strict end of the twin's 95 % interval) with the model's parameters for them and
the state it would have reached on them since the start. A tightening never lowers the estimate: a state
that would read cooler is not taken (the parameters are).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

__all__ = ["SafetyThermal", "ThermalTightening"]


@dataclass(frozen=True)
class ThermalTightening:
    """Stricter values for the safety's thermal model, and what they make of it (a mailbox message)."""

    found_s: float  # device time of the twin's window that found them [s]
    values: dict[str, float]  # config key -> the value in force from now (only the keys that tighten)
    previous: dict[str, float]  # config key -> the value in force before
    params: np.ndarray  # the model's parameters on all the values in force
    constants: dict[str, float]  # its plant constants (the SMA's supply)
    duty_scale: float  # its effort at full duty (the TCP's max_power_w)
    delta_x: np.ndarray = field(default_factory=lambda: np.zeros(0))  # the state's gain on the new values [C]

    def text(self) -> str:
        """One line: each value, from what."""
        return ", ".join(f"{k} = {v:.4g} (was {self.previous.get(k, float('nan')):.4g})"
                         for k, v in self.values.items())


class SafetyThermal:
    """The supervisor's estimate in device time; see the module docstring."""

    def __init__(self, model: Any) -> None:
        self.model = model
        self.t_s: float | None = None  # device time the model has reached
        self.held = 0.0  # the duty on the device since the last command
        self.changes: list[dict[str, Any]] = []  # each tightening taken: when, the values, the temperature

    @property
    def temperature_c(self) -> float:
        return self.model.temperature_c

    def _to(self, t_s: float) -> None:
        """The model at ``t_s``: the duty held over the periods not yet covered (a burst's)."""
        if self.t_s is not None and t_s > self.t_s:
            self.model.step(self.held, t_s - self.t_s)
            self.t_s = t_s

    def apply(self, t_s: float, duty: float, period_s: float) -> float:
        """A command of ``duty`` at ``t_s``, held for ``period_s``: the model to ``t_s + period_s``; T [C]."""
        if self.t_s is None:
            self.t_s = t_s
        self._to(t_s)
        end = t_s + period_s
        temp = self.model.step(duty, end - self.t_s) if end > self.t_s else self.model.temperature_c
        self.t_s = max(self.t_s, end)
        self.held = duty
        return temp

    def state_at(self, t_s: float) -> np.ndarray:
        """The model's state at ``t_s`` (a sample's time, before its command): what the observer takes."""
        self._to(t_s)
        return self.model.x

    def tighten(self, t_s: float, change: ThermalTightening) -> bool:
        """Take ``change`` at device time ``t_s`` (between two cycles); False for a model that takes none."""
        model = self.model
        if not hasattr(model, "retune"):
            return False
        before = model.temperature_c
        model.retune(change.params, change.constants, change.duty_scale)
        kept = model.x.copy()
        if change.delta_x.size == kept.size:
            model.set_state(kept + change.delta_x)
            if model.temperature_c < before:  # never read cooler than before: the state stays as it was
                model.set_state(kept)
        self.changes.append({"t_s": round(t_s, 4), "found_s": round(change.found_s, 4), "values": dict(change.values),
                             "previous": dict(change.previous), "temperature_before_c": round(before, 3),
                             "temperature_after_c": round(model.temperature_c, 3)})
        return True


class ObserverFollow:
    """A controller's thermal observer following the supervisor's estimate: at each step, before its output
    is sampled, the observer's states (``observer_`` copies of the same plant parts, ``plants/thermal.py``)
    are set to the estimate's, so its ceiling acts on the very temperature the supervisor trips on, tightened
    values and all; a ``PeakAfterCut`` beside the observer (the TCP coil's bound after a cut) takes the
    modal form of the same state (``models.lti.modal_form``)."""

    def __init__(self, supervisor: Any, src: list[int], dst: list[int],
                 peak: tuple[list[int], list[int], np.ndarray] | None) -> None:
        self.supervisor, self.src, self.dst, self.peak = supervisor, np.array(src), np.array(dst), peak

    @classmethod
    def of(cls, supervisor: Any, diagram: Any, prefix: str) -> ObserverFollow | None:
        """For a controller ``diagram`` whose observer parts carry ``prefix``; None when the supervisor's
        estimate is not the plant's thermal model or the controller carries no copy of it."""
        from rehab_hil.models.lti import PeakAfterCut, modal_form

        model = getattr(supervisor, "thermal", None)
        if model is None or not hasattr(model, "state_names"):
            return None
        names = diagram.state_names
        pairs = [(i, names.index(prefix + s)) for i, s in enumerate(model.state_names) if prefix + s in names]
        if not pairs:
            return None
        peak = None
        cut = next((p for p in diagram.parts if isinstance(p, PeakAfterCut)), None)
        source = next((p for p in diagram.parts if p.signal_names == (prefix + model.temperature,)), None)
        form = modal_form(source) if cut is not None and source is not None else None
        if form is not None:
            mine = [i for i, s in enumerate(model.state_names) if s.startswith(source.name[len(prefix):] + ".")]
            first = names.index(f"{cut.name}.{cut.states[0]}")
            peak = (mine, list(range(first, first + len(mine))), form[3])
        return cls(supervisor, [a for a, _ in pairs], [b for _, b in pairs], peak)

    def __call__(self, t_s: float, x: np.ndarray) -> None:
        """The controller's states ``x`` at device time ``t_s`` take the estimate's."""
        est = self.supervisor.thermal_state(t_s)
        x[self.dst] = est[self.src]
        if self.peak is not None:
            src, dst, to_modal = self.peak
            x[dst] = to_modal @ est[src]
