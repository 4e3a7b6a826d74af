"""Designing a controller's settings on the (augmented) model: a search on the simulated closed loop.

Each candidate setting is judged the way a session is: ``offline_session`` runs the controller
with its plant model (the feedforward learned anew when a learning setting changes) and the cost
is the per-cycle RMSE plus a tenth of the worst error; a candidate the pre-flight run refuses (it
would trip the rig) is out. A coordinate search halves and doubles one setting at a time and
keeps a change only when it lowers the cost by more than ``MIN_GAIN``: a few dozen closed-loop
runs, each a few seconds. Where the plant has a linear model (``linear_model``), python-control
gives the feedback loop's gain and phase margins for the chosen gains.
"""

from __future__ import annotations

import math
import sys
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any

from rehab_hil.controllers.base import ControllerError, Reference, offline_session
from rehab_hil.controllers.build import build_controller
from rehab_hil.plants.registry import get_plant
from rehab_hil.plants.sections import PlantConfig

__all__ = ["MIN_GAIN", "Tuned", "feedback_margins", "tune"]

MIN_GAIN = 0.03  # a change is kept when it lowers the cost by more than 3 %
_FACTORS = (0.5, 2.0)


@dataclass
class Tuned:
    """The search's outcome: settings before and after, and the session figures of each."""

    name: str
    before: dict[str, float]
    after: dict[str, float]
    figures_before: dict[str, float]
    figures_after: dict[str, float]
    evaluations: int
    trail: list[str] = field(default_factory=list)


def _cost(figures: dict[str, float]) -> float:
    return figures["rmse_deg"] + 0.1 * figures["max_error_deg"]


def _candidates(settings: Any) -> list[str]:
    """The settings worth moving: nonzero gains and learning terms (a zero stays a design choice)."""
    keys = ("kp_per_deg", "ki_per_deg_s", "kd_s_per_deg", "learning_gain_per_deg", "learning_lead_s",
            "learning_release_lead_s", "learning_leak")
    values = settings.model_dump()
    return [k for k in keys if isinstance(values.get(k), float) and values[k] > 0.0]


def tune(cfg: PlantConfig, name: str, source: str = "<config>", cycles: int = 3, passes: int = 2,
         progress: Callable[[str], None] | None = None) -> Tuned:
    """Search ``[controllers.<name>]`` on the model of ``cfg`` for the lowest session cost."""
    spec_settings = cfg.controllers.get(name)
    if spec_settings is None:
        raise ControllerError(f"{source}: no [controllers.{name}] table to start the search from")
    ref = Reference.session(cfg)
    evaluations = 0

    def judge(settings: Any) -> dict[str, float] | None:
        nonlocal evaluations
        evaluations += 1
        trial = cfg.model_copy(update={"controllers": {**cfg.controllers, name: settings}})
        try:
            ctl = build_controller(trial, name, ref, source=source)
        except ControllerError:
            return None
        return offline_session(ctl, cycles)[1]

    best = spec_settings
    best_fig = judge(best)
    if best_fig is None:
        raise ControllerError(f"{source}: [controllers.{name}] as it is would trip the rig on the model; "
                              "start the search from settings that run")
    first_fig = dict(best_fig)
    trail: list[str] = []
    for _ in range(passes):
        improved = False
        for key in _candidates(best):
            for factor in _FACTORS:
                value = getattr(best, key) * factor
                try:
                    trial = type(best).model_validate({**best.model_dump(), key: value})
                except ValueError:
                    continue
                fig = judge(trial)
                if fig is None or not math.isfinite(_cost(fig)):
                    continue
                if _cost(fig) < (1.0 - MIN_GAIN) * _cost(best_fig):
                    trail.append(f"{key} {getattr(best, key):.4g} -> {value:.4g}: cost "
                                 f"{_cost(best_fig):.3f} -> {_cost(fig):.3f}")
                    if progress:
                        progress(trail[-1])
                    best, best_fig, improved = trial, fig, True
                    break
        if not improved:
            break
    return Tuned(name, spec_settings.model_dump(), best.model_dump(), first_fig, best_fig, evaluations, trail)


def feedback_margins(cfg: PlantConfig, gains: Any) -> dict[str, float] | None:
    """Gain margin [dB], phase margin [deg] and crossover [rad/s] of the PID on the encoder angle
    around the plant's linear model (python-control), or None when the plant has none."""
    linear = getattr(sys.modules[get_plant(cfg.plant).__module__], "linear_model", None)
    if linear is None:
        return None
    import control  # python-control takes seconds to import: only where it is used

    plant = linear(cfg)[0, 0]  # the actuator input -> angle [rad]
    deg = 180.0 / math.pi
    tf = gains.derivative_filter_s
    pid = control.tf([gains.kd_s_per_deg * deg, gains.kp_per_deg * deg, gains.ki_per_deg_s * deg], [1.0, 0.0])
    if tf > 0:
        pid = pid * control.tf([1.0], [tf, 1.0])
    gm, pm, _, wc = control.margin(pid * plant)
    return {"gain_margin_db": 20.0 * math.log10(gm) if gm and math.isfinite(gm) else math.inf,
            "phase_margin_deg": float(pm), "crossover_rad_s": float(wc)}


def write_settings(text: str, name: str, settings: dict[str, Any]) -> str:
    """The config text with ``[controllers.<name>]``'s values replaced (comments kept; a key the
    table lacked is added under its header)."""
    import re

    lines = text.splitlines()
    start = next((i for i, ln in enumerate(lines) if ln.strip().startswith(f"[controllers.{name}]")), None)
    if start is None:
        raise ValueError(f"the config has no [controllers.{name}] table")
    end = next((i for i in range(start + 1, len(lines)) if lines[i].lstrip().startswith("[")), len(lines))
    done = set()
    for i in range(start + 1, end):
        m = re.match(r"^(\s*)([A-Za-z_][A-Za-z0-9_]*)(\s*=\s*)([^#]*?)(\s*)(#.*)?$", lines[i])
        if not (m and settings.get(m.group(2)) is not None):
            continue
        head = f"{m.group(1)}{m.group(2)}{m.group(3)}{_toml(settings[m.group(2)])}"
        comment = m.group(6)
        if comment:  # the comment stays in its column
            column = len(lines[i]) - len(comment)
            head = f"{head:<{column}}{comment}" if len(head) < column else f"{head}  {comment}"
        lines[i] = head
        done.add(m.group(2))
    extra = [f"{k} = {_toml(v)}" for k, v in settings.items() if k not in done and v is not None]
    lines[start + 1:start + 1] = extra
    return "\n".join(lines) + "\n"


def _toml(v: Any) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, float):
        return repr(round(v, 6))
    return repr(v) if not isinstance(v, str) else f'"{v}"'


def settings_table(before: dict[str, Any], after: dict[str, Any], keys: Sequence[str] | None = None) -> list[str]:
    """Lines ``key: before -> after`` for the settings that changed."""
    return [f"{k}: {before[k]} -> {after[k]}" for k in (keys or after) if before.get(k) != after.get(k)]
