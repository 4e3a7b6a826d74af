"""What a rehabilitation session did, cycle by cycle: tracking, range of motion, time to open and
to close, peak actuator temperature and electrical energy (the figures a therapist and a rig
owner compare across sessions and controllers).

A cycle of the open-close reference (``rehab_hil.controllers.Reference``) starts closed, moves
open over ``move_s``, holds, moves back and holds. "Reached" means within ``REACH_SHARE`` of the
span from the target. The same function serves the live loop (one cycle at a time, after the
command is out), the run summary, ``metadata.json`` and the offline benchmark.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import asdict, dataclass, field, replace

import numpy as np

from rehab_hil.therapy_measures import cycle_measures

__all__ = ["REACH_SHARE", "CycleMetrics", "SessionMeter", "cycle_metrics", "session_summary"]

REACH_SHARE = 0.05  # within 5 % of the span from the target counts as reached


@dataclass(frozen=True)
class CycleMetrics:
    """One open-close cycle (angles in deg, times in s from the start of each move)."""

    index: int
    start_s: float
    rmse_deg: float
    max_error_deg: float
    rom_deg: float  # range of motion reached: largest minus smallest angle
    time_to_open_s: float  # nan: never reached
    time_to_closed_s: float
    peak_temperature_c: float  # the actuator temperature estimate (nan: none)
    energy_j: float  # electrical energy into the actuator
    # what a therapist reads (``therapy_measures.cycle_measures``: success, assistance ratio, smoothness ...)
    measures: Mapping[str, float] = field(default_factory=dict)

    def as_dict(self) -> dict[str, float]:
        d = asdict(self)
        return {**{k: v for k, v in d.items() if k != "measures"}, **d["measures"]}


def _reach_time(t: np.ndarray, angle: np.ndarray, target: float, tol: float, since: float) -> float:
    after = t >= since - 1e-12
    hit = np.flatnonzero(after & (np.abs(angle - target) <= tol))
    return float(t[hit[0]] - since) if hit.size else math.nan


def cycle_metrics(t: np.ndarray, reference: np.ndarray, angle: np.ndarray, power_w: np.ndarray,
                  temperature_c: np.ndarray | None, period_s: float, move_s: float, closed_deg: float,
                  open_deg: float, complete_only: bool = True) -> list[CycleMetrics]:
    """Metrics of each cycle in the record (``t`` from the session's start, samples in order);
    ``complete_only`` drops a last cycle the record cuts short."""
    t, reference, angle, power_w = (np.asarray(a, float) for a in (t, reference, angle, power_w))
    temp = None if temperature_c is None else np.asarray(temperature_c, float)
    if t.size == 0:
        return []
    tol = REACH_SHARE * abs(open_deg - closed_deg)
    hold = 0.5 * (period_s - 2.0 * move_s)
    n_cycles = math.floor((t[-1] + 1e-9) / period_s) + 1
    out = []
    for c in range(n_cycles):
        t0 = c * period_s
        sel = (t >= t0) & (t < t0 + period_s)
        if not sel.any():
            continue
        if complete_only and t[sel][-1] < t0 + period_s - 2.0 * _step(t):
            break
        tc, rc, ac, pc = t[sel], reference[sel], angle[sel], power_w[sel]
        ok = np.isfinite(rc) & np.isfinite(ac)
        err = (ac - rc)[ok]
        dt = np.diff(tc, append=tc[-1] + _step(t))
        tempc = temp[sel] if temp is not None else None
        out.append(CycleMetrics(
            index=c, start_s=float(t0),
            rmse_deg=float(np.sqrt(np.mean(err**2))) if err.size else math.nan,
            max_error_deg=float(np.max(np.abs(err))) if err.size else math.nan,
            rom_deg=float(np.nanmax(ac) - np.nanmin(ac)),
            time_to_open_s=_reach_time(tc, ac, open_deg, tol, t0),
            time_to_closed_s=_reach_time(tc, ac, closed_deg, tol, t0 + move_s + hold),
            peak_temperature_c=float(np.nanmax(tempc)) if tempc is not None and np.isfinite(tempc).any()
            else math.nan,
            energy_j=float(np.sum(np.nan_to_num(pc) * dt)),
        ))
    return out


def _step(t: np.ndarray) -> float:
    return float(np.median(np.diff(t))) if t.size > 1 else 0.0


def session_summary(cycles: Sequence[CycleMetrics]) -> dict[str, float]:
    """The session in a few figures: mean per-cycle values, worst error, hottest cycle."""
    if not cycles:
        return {"cycles": 0.0}

    def mean(key: str) -> float:
        v = np.array([getattr(c, key) for c in cycles], float)
        return float(np.nanmean(v)) if np.isfinite(v).any() else math.nan

    def worst(key: str) -> float:
        v = np.array([getattr(c, key) for c in cycles], float)
        return float(np.nanmax(v)) if np.isfinite(v).any() else math.nan

    out = {"cycles": float(len(cycles)), "rmse_deg": mean("rmse_deg"), "max_error_deg": worst("max_error_deg"),
           "rom_deg": mean("rom_deg"), "time_to_open_s": mean("time_to_open_s"),
           "time_to_closed_s": mean("time_to_closed_s"), "peak_temperature_c": worst("peak_temperature_c"),
           "energy_per_cycle_j": mean("energy_j")}
    for key in ("success", "success_assisted", "assistance_ratio", "sparc", "ldlj", "peak_velocity_deg_s",
                "patient_torque_open_nm", "patient_torque_close_nm"):
        v = np.array([c.measures.get(key, math.nan) for c in cycles], float)
        if np.isfinite(v).any():  # the therapist's measures, averaged over the cycles (success: its rate)
            out[key] = float(np.nanmean(v))
    return out


class SessionMeter:
    """Per-cycle figures while a session runs: the loop adds each recorded row (the sample's angle,
    the reference of the command in force when it arrived: run.csv's row; after the command is out)
    and ``poll`` returns a cycle's metrics once that cycle has ended. Arrays are
    preallocated for the session; one cycle's figures cost a few numpy passes every cycle period."""

    def __init__(self, capacity: int, period_s: float, move_s: float, first_open_s: float, closed_deg: float,
                 open_deg: float, power_w: Callable[[np.ndarray, np.ndarray], np.ndarray],
                 baseline_energy_j: float = math.nan, interaction: tuple[str, float] | None = None,
                 assisted: tuple[str, ...] = ("open", "close"), count_deg: float = 0.0) -> None:
        self.period_s, self.move_s, self.first_open_s = period_s, move_s, first_open_s
        # the moves the rig can drive: an actuator that pulls one way (an SMA wire, a TCP muscle) drives
        # the opening move only; the other is the spring's and the patient's (``success_assisted``)
        self.assisted = assisted
        self.count_deg = count_deg  # the encoder's count: a move's success tolerance includes it [deg]
        self.closed_deg, self.open_deg, self.power_w = closed_deg, open_deg, power_w
        self.baseline_energy_j = baseline_energy_j  # the robot's energy per cycle with a passive patient [J]
        self.interaction = interaction  # (the torque sensor's channel, its sign on the axis), or None
        n = max(1, capacity)
        self._cols = np.full((7, n), np.nan)  # t, reference, angle, effort, velocity, temperature, patient torque
        self.n = 0
        self._done_upto = 0  # samples already part of a reported cycle
        self._next_end = first_open_s + period_s
        self.cycles: list[CycleMetrics] = []

    def add(self, t_s: float, reference_deg: float, angle_deg: float, effort: float, velocity_rad_s: float,
            temperature_c: float, torque_nm: float = math.nan) -> None:
        if self.n < self._cols.shape[1]:
            self._cols[:, self.n] = (t_s, reference_deg, angle_deg, effort, velocity_rad_s, temperature_c, torque_nm)
            self.n += 1

    def torque_of(self, analog: Mapping[str, float]) -> float:
        """The patient's torque on the axis from the sample's ADC values (nan: no torque sensor)."""
        if self.interaction is None:
            return math.nan
        signal, sign = self.interaction
        return sign * analog.get(signal, math.nan)

    def poll(self) -> CycleMetrics | None:
        """The cycle that has just ended (a sample past its end added), else None."""
        if self.n == 0 or self._cols[0, self.n - 1] < self._next_end:
            return None
        start, end = self._next_end - self.period_s, self._next_end
        self._next_end += self.period_s
        c = self._cols[:, self._done_upto:self.n]
        inside = (c[0] >= start) & (c[0] < end)
        self._done_upto += int(np.searchsorted(c[0], end))
        if inside.sum() < 2:
            return None
        c = c[:, inside]
        found = cycle_metrics(c[0] - start, c[1], c[2], self.power_w(c[3], c[4]), c[5], self.period_s, self.move_s,
                              self.closed_deg, self.open_deg, complete_only=False)
        if not found:
            return None
        try:
            measures = cycle_measures(c[0] - start, c[2], c[4], c[6], self.period_s, self.move_s, self.closed_deg,
                                      self.open_deg, found[0].energy_j, self.baseline_energy_j, self.count_deg)
            measures["success_assisted"] = float(np.nanmean([measures[f"success_{d}"] for d in self.assisted]))
        except (ArithmeticError, ValueError):  # runs in the loop: a measure that cannot be had is left out,
            measures = {}                       # never a trip (a 1e-200 rad/s speed once underflowed in LDLJ)
        cycle = replace(found[0], index=len(self.cycles), start_s=float(start), measures=measures)
        self.cycles.append(cycle)
        return cycle

    def summary(self) -> dict[str, float]:
        return session_summary(self.cycles)
