"""What a therapist reads of one open-close cycle: success, the assistance ratio, active range of
motion, peak velocity, smoothness (SPARC, log dimensionless jerk), the patient's torque with its
interval, a spasticity indicator and the interaction stiffness.

A cycle (``session_metrics``) starts with its opening move. A move **succeeds** when the angle is
within ``REACH_SHARE`` of the span from its target, widened by one encoder count (``count_deg``: a
reading lies up to a count from the angle), by ``move_s + SUCCESS_WINDOW_S`` after the move starts
(the FINGER robot's targets hit: Rowe et al. 2017). The **assistance ratio** is the robot's
electrical energy in the cycle over what the same controller, at full assistance, spends on the
host's model, whose finger is passive. Smoothness is computed on the opening move's speed profile.
The torque measures need a torque sensor between the patient and the rig (the Finger Extensor's):
on a rig without one they are nan. Units in every key.
"""

from __future__ import annotations

import math

import numpy as np

from rehab_hil.smoothness import log_dimensionless_jerk, sparc

__all__ = ["SPASTIC_SPEED_RAD_S", "SUCCESS_WINDOW_S", "cycle_measures", "move_success", "move_windows",
           "success_tolerance_deg"]

SUCCESS_WINDOW_S = 1.0  # a move may take this long past its planned end to reach its target [s]
SPASTIC_SPEED_RAD_S = 0.5  # the velocity-dependent resistance is fitted on samples faster than this [rad/s]
REACH_SHARE = 0.05  # as session_metrics: within 5 % of the span counts as reached
SMOOTHNESS_RATE_HZ = 100.0  # speed is averaged down to this rate for smoothness (the reference implementation's
#                             example rate): the encoder's 1 kHz finite differences are quantisation noise above it


def _resampled(speed: np.ndarray, fs_hz: float) -> tuple[np.ndarray, float]:
    """``speed`` averaged over blocks down to about ``SMOOTHNESS_RATE_HZ`` (and that rate)."""
    k = max(1, round(fs_hz / SMOOTHNESS_RATE_HZ)) if math.isfinite(fs_hz) else 1
    n = speed.size // k
    return (speed[:n * k].reshape(n, k).mean(axis=1), fs_hz / k) if n >= 3 else (speed, fs_hz)


def move_success(t: np.ndarray, angle_deg: np.ndarray, target_deg: float, tol_deg: float, start_s: float,
                 move_s: float) -> float:
    """1.0 if the angle is within ``tol_deg`` of ``target_deg`` by ``move_s + SUCCESS_WINDOW_S`` after
    ``start_s``, else 0.0 (nan: no samples in the window)."""
    sel = (t >= start_s) & (t <= start_s + move_s + SUCCESS_WINDOW_S)
    if not sel.any():
        return math.nan
    return float(np.any(np.abs(angle_deg[sel] - target_deg) <= tol_deg))


def _slope(x: np.ndarray, y: np.ndarray) -> float:
    ok = np.isfinite(x) & np.isfinite(y)
    if ok.sum() < 3 or np.ptp(x[ok]) == 0.0:
        return math.nan
    return float(np.polyfit(x[ok], y[ok], 1)[0])


def _toward(torque: np.ndarray, window: np.ndarray, sign: float, key: str) -> dict[str, float]:
    """The mean torque toward one move's target over its window, and the half-width of its 95 % interval."""
    v = sign * torque[window]
    v = v[np.isfinite(v)]
    return {f"patient_torque_{key}_nm": float(np.mean(v)) if v.size else math.nan,
            f"patient_torque_{key}_ci_nm": float(1.96 * np.std(v) / math.sqrt(v.size)) if v.size > 1 else math.nan}


def _torque_measures(t: np.ndarray, angle_rad: np.ndarray, velocity: np.ndarray, torque: np.ndarray,
                     windows: tuple[np.ndarray, np.ndarray], direction: float) -> dict[str, float]:
    """The patient's torque toward each move's target (per direction: mean, 95 % interval), the
    interaction stiffness and the velocity-dependent resistance (from the torque sensor, on the axis)."""
    opening, closing = windows
    if not np.isfinite(torque).any():
        return {**{f"patient_torque_{d}{ci}_nm": math.nan for d in ("open", "close") for ci in ("", "_ci")},
                "interaction_stiffness_nm_per_rad": math.nan, "resistance_slope_nm_s_per_rad": math.nan}
    fast = opening & (np.abs(velocity) > SPASTIC_SPEED_RAD_S)
    return {
        **_toward(torque, opening, direction, "open"), **_toward(torque, closing, -direction, "close"),
        "interaction_stiffness_nm_per_rad": -_slope(angle_rad, torque),
        "resistance_slope_nm_s_per_rad": -_slope(velocity[fast], torque[fast]),
    }


def move_windows(period_s: float, move_s: float) -> tuple[tuple[float, float], tuple[float, float]]:
    """The opening and the closing move's windows from the cycle's start [s]: each move and the
    ``SUCCESS_WINDOW_S`` it may take past its planned end (the torque measures are means over them)."""
    hold = 0.5 * (period_s - 2.0 * move_s)
    return (0.0, move_s + SUCCESS_WINDOW_S), (move_s + hold, 2 * move_s + hold + SUCCESS_WINDOW_S)


def success_tolerance_deg(closed_deg: float, open_deg: float, count_deg: float = 0.0) -> float:
    """How near its target a move must come: 5 % of the span and one encoder count (the TCP finger's
    2 deg task: 0.1 deg, below its 0.18 deg count, so a finger 0.07 deg short read a count short and failed)."""
    return REACH_SHARE * abs(open_deg - closed_deg) + count_deg


def cycle_measures(t: np.ndarray, angle_deg: np.ndarray, velocity_rad_s: np.ndarray, torque_nm: np.ndarray,
                   period_s: float, move_s: float, closed_deg: float, open_deg: float, energy_j: float,
                   baseline_energy_j: float, count_deg: float = 0.0) -> dict[str, float]:
    """The therapist's measures of one cycle; ``t`` from the cycle's start [s], ``torque_nm`` the
    patient's torque on the axis (nan: no sensor), ``baseline_energy_j`` the robot's energy per cycle
    with a passive patient (nan: unknown), ``count_deg`` the encoder's count."""
    t, angle, vel, torque = (np.asarray(a, float) for a in (t, angle_deg, velocity_rad_s, torque_nm))
    tol = success_tolerance_deg(closed_deg, open_deg, count_deg)
    hold = 0.5 * (period_s - 2.0 * move_s)
    ok_open = move_success(t, angle, open_deg, tol, 0.0, move_s)
    ok_close = move_success(t, angle, closed_deg, tol, move_s + hold, move_s)
    (_, open_end), (close_start, close_end) = move_windows(period_s, move_s)
    opening = t <= open_end
    closing = (t >= close_start) & (t <= close_end)
    speed = np.abs(np.nan_to_num(vel[opening]))
    step = float(np.median(np.diff(t))) if t.size > 1 else 0.0
    fs = 1.0 / step if step > 0 else math.nan
    smooth, fs_smooth = _resampled(speed, fs)
    direction = 1.0 if open_deg >= closed_deg else -1.0
    ratio = energy_j / baseline_energy_j if baseline_energy_j and math.isfinite(baseline_energy_j) else math.nan
    return {
        "success_open": ok_open, "success_close": ok_close, "success": float(np.nanmean([ok_open, ok_close])),
        "assistance_ratio": ratio,
        "active_rom_deg": float(np.nanmax(angle) - np.nanmin(angle)) if np.isfinite(angle).any() else math.nan,
        "peak_velocity_deg_s": float(np.degrees(speed.max())) if speed.size else math.nan,
        "sparc": sparc(smooth, fs_smooth) if smooth.size > 2 else math.nan,
        "ldlj": log_dimensionless_jerk(smooth, fs_smooth) if smooth.size > 2 else math.nan,
        **_torque_measures(t, np.radians(angle), vel, torque, (opening, closing), direction),
    }
