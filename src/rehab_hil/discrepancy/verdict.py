"""What the workflow may conclude: near-aliases said plainly, and a residual nothing explains.

Near-aliases: two significant candidates of a round whose held-out BIC lie within
``ALIAS_DELTA_BIC`` of each other, or whose held-out RMS errors on the channel the chosen one cuts
most differ by less than ``ALIAS_RMS_SHARE`` (relative), or where the fit part prefers the one the
held-out part ranks second, explain the residual about equally. The
verdict names both, says this record cannot tell them apart, and suggests the experiment that
would (``EXPERIMENTS``; a generic hint otherwise). A nominal parameter within the BIC margin of
an effect is chosen before it (no new structure when a known one explains the data as well); the
RMS criterion alone only makes the statement.

Unexplained residual: after the search, a channel whose held-out RMS error exceeds both
``NOISE_FACTOR`` times its noise floor (the measured signal's sample-to-sample scatter, which
includes quantisation) and ``SPREAD_SHARE`` of its spread (its std: the normalised RMS error of a
"fit" percentage) is not explained by the model; the
verdict says so, with the channel, the time window and the state region where it sits, instead
of calling the model a fit.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable, Mapping, Sequence
from typing import Any, Protocol, TypeVar

import numpy as np

from rehab_hil.discrepancy import localise

__all__ = ["ALIAS_DELTA_BIC", "ALIAS_RMS_SHARE", "EXPERIMENTS", "NOISE_FACTOR", "SPREAD_SHARE", "channel_unit",
           "experiment", "is_alias", "noise_floor", "residual_stats", "tied_parameter", "unexplained",
           "unexplained_channels"]

ALIAS_DELTA_BIC = 10.0  # the significance margin (selection.MIN_DELTA_BIC): less is not "very strong"
ALIAS_RMS_SHARE = 0.10  # held-out RMS on the decisive channel within 10 % of each other
NOISE_FACTOR = 4.0
SPREAD_SHARE = 0.02  # the model reproduces 98 % of the channel's spread (NRMSE fit)

EXPERIMENTS: dict[frozenset[str], str] = {
    frozenset({"contact_spring_damper", "passive_muscle"}):
        "a slow ramp through the contact angle: a contact engages at an angle, a passive muscle stiffens "
        "smoothly from rest",
    frozenset({"coulomb_friction", "viscous_friction"}):
        "moves at several constant speeds: Coulomb friction does not grow with speed, viscous does",
    frozenset({"backlash", "time_delay"}):
        "reversals at two different speeds: a play costs a fixed angle, a delay a fixed time",
    frozenset({"coulomb_friction", "actuator_dead_zone"}):
        "slow moves against a known load: friction opposes motion, a dead zone "
        "removes a fixed part of the command whatever the load",
    frozenset({"coulomb_friction", "motor.kt_nm_per_a"}):
        "hold the iris against known patient torques in both directions while logging the current: friction "
        "costs a fixed torque against the motion, a torque constant scales every ampere",
    frozenset({"motor.kt_nm_per_a", "motor.resistance_ohm"}):
        "log the motor current through a stall: the current fixes R, the torque per ampere fixes k_t",
    frozenset({"drive.supply_voltage_v", "sma.h1_w_per_m2_c"}):
        "measure the supply under load, or log the wire temperature while cooling (h1 sets the cooling rate)",
}


def experiment(a: str, b: str, descriptions: Mapping[str, str]) -> str:
    """The experiment that would tell ``a`` from ``b``."""
    known = EXPERIMENTS.get(frozenset({a, b}))
    if known:
        return known
    return (f"an excitation where the two act differently ({a}: {descriptions.get(a, a)}; "
            f"{b}: {descriptions.get(b, b)})")


def is_alias(bic_a: float, bic_b: float, rms_a: float, rms_b: float,
             train_a: float | None = None, train_b: float | None = None) -> bool:
    """Do two candidates explain the residual about equally? ``rms_*``: their held-out RMS on the
    channel the chosen one cuts most; ``train_*``: their cost on the fit part. ``a`` (chosen on the
    held-out part) and ``b`` are also aliases when the fit part prefers ``b``: the record's two halves
    disagree (an SMA record with a hidden passive muscle: the muscle fitted the first 12 s better, as
    a steeper exponential, and a contact spring the held-out part, whose bends went further)."""
    split = train_a is not None and train_b is not None and train_b < train_a
    return (abs(bic_a - bic_b) < ALIAS_DELTA_BIC or abs(rms_a - rms_b) <= ALIAS_RMS_SHARE * max(rms_a, rms_b)
            or split)


def noise_floor(y: np.ndarray) -> float:
    """Sample-to-sample scatter of a measured channel: std of the second difference / sqrt 6 (white
    noise of std s gives 6 s^2; a smooth motion adds only its curvature, where a first difference
    would count its speed as noise), outliers beyond 10 robust sigmas left out."""
    y = np.asarray(y, float)
    d = np.diff(y[np.isfinite(y)], 2)
    if d.size < 2:
        return 0.0
    mad = float(np.median(np.abs(d - np.median(d))))
    if mad > 0.0:  # a few jumps (where several records are joined end to end) are not noise: beyond 10 robust
        d = d[np.abs(d - np.median(d)) <= 10.0 * 1.4826 * mad]  # sigmas they are left out (4.6e2 deg was read)
    return float(np.std(d) / np.sqrt(6.0))


_UNITS = {"deg": "deg", "rad": "rad", "m": "m", "mm": "mm", "n": "N", "nm": "N m", "c": "C", "a": "A", "v": "V",
          "counts": "counts", "w": "W", "ratio": "", "s": "s"}
_RATE_UNITS = {"rad_s": "rad/s", "deg_s": "deg/s", "m_s": "m/s"}


def channel_unit(name: str) -> str:
    """The unit a signal's name ends in, as a person writes it: angle_deg -> deg, velocity_rad_s -> rad/s."""
    for suffix, unit in _RATE_UNITS.items():
        if name.endswith("_" + suffix):
            return unit
    return _UNITS.get(name.rsplit("_", 1)[-1], "")


def residual_stats(y: np.ndarray, rms: float) -> dict[str, float | bool]:
    """A channel's held-out residual beside what the data say about it: the noise floor (``noise_floor``),
    the spread (std), the residual's share of the spread, and whether it is at the noise floor (within
    ``NOISE_FACTOR`` floors: only then does the model fit "within the noise")."""
    floor, spread = noise_floor(y), float(np.std(y))
    return {"rms": float(rms), "noise_floor": floor, "spread": spread,
            "share_of_spread": float(rms) / spread if spread > 0 else float("inf"),
            "at_noise": bool(rms <= NOISE_FACTOR * floor)}


def unexplained_channels(channels: Sequence[str], measured: Mapping[str, np.ndarray],
                         residual_rms: Mapping[str, float]) -> dict[str, dict[str, float]]:
    """Channels whose held-out RMS error the noise and a small share of the spread cannot account
    for: channel -> {rms, noise_floor, spread, threshold} in the channel's unit."""
    out = {}
    for c in channels:
        y = measured[c]
        floor, spread = noise_floor(y), float(np.std(y))
        thr = max(NOISE_FACTOR * floor, SPREAD_SHARE * spread)
        if residual_rms[c] > thr:
            out[c] = {"rms": float(residual_rms[c]), "noise_floor": floor, "spread": spread, "threshold": thr}
    return out


class _Kinded(Protocol):
    @property
    def kind(self) -> str: ...


K = TypeVar("K", bound=_Kinded)


def tied_parameter(best: K, others: Iterable[K], ties: Callable[[K], bool]) -> K | None:
    """A known parameter before new structure: when ``best`` is an effect, the first parameter among
    ``others`` that ``ties`` with it is named instead (None: ``best`` stays). The workflow's tie is a
    held-out BIC within ``ALIAS_DELTA_BIC``, the twin's a leftover residual within a share of the best's."""
    if best.kind != "effect":
        return None
    return next((c for c in others if c.kind == "parameter" and ties(c)), None)


def unexplained(replay: Any, current: dict[str, np.ndarray], split_s: float,
                 kinds: dict[str, str]) -> tuple[dict[str, dict[str, float]], dict[str, Any]]:
    """The channels whose held-out error the final model leaves beyond the noise (the workflow's step 3), and where
    the residual is largest: the time window and the state region."""
    hm = replay.t >= split_s
    rms = {c: float(np.sqrt(np.mean((current[c][hm] - replay.measured[c][hm]) ** 2))) for c in replay.channels}
    unexpl = unexplained_channels(replay.channels, {c: replay.measured[c] for c in replay.channels}, rms)
    if not unexpl:
        return unexpl, {}
    r = replay.residual(current)
    combined = np.sqrt(np.mean(r**2, axis=0))
    win = max(localise.time_windows(replay.t, combined), key=lambda w: w["rms"])
    regs = [g for g in localise.regions(replay.t, replay.measured, r, replay.channels, kinds)
            if g["ratio"] == g["ratio"]]
    top = max(regs, key=lambda g: float(g["ratio"])) if regs else {"region": "everywhere"}  # type: ignore[arg-type]
    return unexpl, {"window_start_s": win["start_s"], "window_end_s": win["end_s"], "region": top["region"]}
