"""The patient's torque on the joint, estimated online from the host's model and the rig's own
sensors: an unknown input found by least squares over each re-anchored segment.

The twin's model knows no patient. Whatever torque the patient puts on the joint shows as the
model's prediction error over a segment that starts from the measured state (the twin's anchoring,
``twin/model.py``). Per whole segment (``segment_s`` of samples, none lost) the patient's torque is
taken as constant: an unknown load on the plant's primary axis (the library's ``constant_load``
effect, which the twin's model carries disabled, switched on at the estimate). The model runs over
the segment at the running estimate, and again with the load nudged and with its start velocity
nudged (the joint's speed is not measured: a wrong start speed and a torque move the angle
differently, t against t squared); the measured channels in their own counts (the encoder, a force
sensor the model predicts: the SMA rig's Flexiforce, the TCP's tendon force) give the torque and
the speed's correction by least squares (Gauss-Newton, the step repeated while it is large), taken
with a random walk's gain. The model then carries on as if it had run on them. A torque sensor
between the patient and the rig (the Finger Extensor's) is not used: its input is held at zero, so
this is the model's figure beside the sensor's. Where the model's joint is held by static friction
any torque inside the band fits: the estimate is the torque that balances the others on the axis.

Per move (a window of a cycle, ``therapy_measures.move_windows``): the mean of the estimates of the
segments whose middle lies in it, toward the move's target, and its 95 % half-interval (``window``).
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from scipy import stats

from rehab_hil.interfaces import DeviceBinding
from rehab_hil.plants.registry import get_plant
from rehab_hil.therapy_measures import move_windows
from rehab_hil.twin.model import TwinModel

__all__ = ["LOAD_PARAM", "TORQUE_RUNS", "PatientTorqueEstimator", "TorqueSegment", "move_torques",
           "patient_torque_estimator"]

LOAD_PARAM = "candidate_constant_load.level_nm"  # the twin model's disabled constant load on the primary axis
SUBSAMPLE = 5  # every this many samples of a segment enter the fit (neighbours are correlated)
NUDGE_NM = 1e-3  # finite-difference step of the torque [N m] (the model is about linear in it)
NUDGE_RAD_S = 1e-2  # ... and of the start velocity [rad/s]
MAX_ITER = 3  # Gauss-Newton steps per segment at most ...
ITER_TOL_NM = 1e-4  # ... while the torque moves more than this [N m]
WALK_NM_PER_S = 0.5  # how fast the patient's torque may change (a random walk's step per second) [N m/s]: the
#                     capable patient's on the Finger Extensor changes by 0.3 N m within about a second
UNSEEN_FACTOR = 5.0  # a segment whose counts set its torque this many times worse than its window's median
#                     segment's says too little (a joint stopping: 8-9x on the Finger Extensor; the SMA's moves <3x)
UNSTICK_COUNTS = 1.5  # a model held where the rig's reading moved more than this many counts from it: not held
UNSTICK_STEPS = 9  # ... the torque tried beyond the band grows to NUDGE_NM x 3^9 = 20 N m at most
HELD_SHARE = 0.1  # a torque nudge one way moving the prediction less than this share of the other way: held
TORQUE_RUNS = 6  # model runs of a segment, typically: the prediction, two nudges, the run at the estimate and
#                  a nudge each way there


@dataclass(frozen=True)
class TorqueSegment:
    """One segment's estimate: its time span on the session clock [s], the patient's torque on the axis
    [N m], its standard error [N m] (for a joint held by static friction, ``held``, the half-width of the
    band the torque lies in instead; nan: not known)."""

    t0_s: float
    t1_s: float
    torque_nm: float
    sd_nm: float
    floor_nm: float = math.nan  # the part of the standard error the sensors' counts set [N m]
    held: bool = False


class PatientTorqueEstimator:
    """The patient's torque per whole segment, from a ``TwinModel`` of its own (``update`` per block of
    samples as ``TwinModel.advance`` takes them; ``window`` per move)."""

    def __init__(self, model: TwinModel, load_index: int, velocity_state: int | None, held_inputs: Sequence[int],
                 axis_torque: str, source: str) -> None:
        """``load_index``: the load's parameter; ``velocity_state``: the axis speed's state (None: not fitted);
        ``held_inputs``: input columns held at zero (a torque sensor's reading); ``axis_torque``: the signal
        the axis's torques are summed on (static friction excepted); ``source``: what it uses."""
        self.model, self.source = model, source
        self._load, self._vel, self._held = load_index, velocity_state, list(held_inputs)
        self._sum_slots = model.system.out_slots([axis_torque])
        self._sum_ws = model.system.workspace()
        self.torque_nm = 0.0
        self.segments: list[TorqueSegment] = []
        u0 = model.inputs_of(0, 0, 0, {})
        self._pinned = np.any(model.anchor_gain != 0.0, axis=0)  # channels whose states the anchoring sets
        self._out_jac = model.output_jacobian(model.x, model.xd, u0)
        self._set(model.P, 0.0)

    def _set(self, P: np.ndarray, torque_nm: float) -> None:
        P[self._load] = -torque_nm  # the load's output is -level on the axis

    def update(self, index: np.ndarray, U: np.ndarray, measured: np.ndarray) -> None:
        """One block of samples (sample indices, model inputs, measured channels in sensor units): each
        whole segment in it gives an estimate; the model carries on through the rest."""
        m = self.model
        U = U.copy()
        U[:, self._held] = 0.0
        whole = (index.size == m.segment_samples and int(index[-1] - index[0]) == index.size - 1 and m.at_anchor)
        if not m.anchored or not whole:  # the inputs over a gap are unknown: nothing sure to learn here
            m.advance(index, U, measured)
            return
        x0, xd0 = m.x.copy(), m.xd.copy()
        steps, at = m.plan(index, U)
        y = m.advance(index, U, measured).predicted
        x_end = m.x - m.anchor_gain @ m.last_correction  # the segment's end before its anchoring
        keep = np.arange(0, at.size, SUBSAMPLE)
        z = measured[keep] / m.resolution
        fit = self._fit((x0, xd0, steps, at[keep]), z, y[keep] / m.resolution, x_end)
        if fit is None:
            return
        step, (sd, floor), dx = fit
        held = not math.isfinite(sd)
        if held:  # held by static friction: the torque that leaves it nothing to hold, the band's middle
            edge = float(step[0])  # the least squares' edge of the band (0: none found)
            step[0] = self._balance(x0, xd0, steps)
            sd = abs(edge - float(step[0])) if edge else math.nan
        else:  # a random walk's Kalman gain: a segment that says little (sd >> the walk) moves the estimate little
            walk = WALK_NM_PER_S * m.segment_samples * m.period_s
            step *= walk**2 / (walk**2 + sd**2)
        if np.any(self._pinned):  # anchoring sets the states a channel is: they do not depend on the fit
            dx -= m.anchor_gain[:, self._pinned] @ (self._out_jac[self._pinned] @ dx)
        m.x += dx @ step
        self.torque_nm += float(step[0])
        self._set(m.P, self.torque_nm)
        t = m.period_s
        self.segments.append(TorqueSegment(float(index[0] * t), float((index[-1] + 1) * t), self.torque_nm, sd,
                                           floor, held))

    def _balance(self, x0: np.ndarray, xd0: np.ndarray, steps: np.ndarray) -> float:
        """The change of the estimate that makes the mean of the axis's torque sum over the segment zero
        (the middle of the static friction's band, where a held joint says no more than that)."""
        s = self.model.system
        _, Y = s.run_arrays(x0.copy(), xd0.copy(), steps, self.model.P, self._sum_slots, self._sum_ws)
        return -float(np.mean(Y[:, 0]))

    def _run(self, segment: tuple[np.ndarray, ...], delta: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The segment's samples (counts) and end state with the torque and start speed moved by ``delta``."""
        x0, xd0, steps, at = segment
        m = self.model
        P = m.P.copy()
        self._set(P, self.torque_nm + delta[0])
        x = x0.copy()
        if self._vel is not None:
            x[self._vel] += delta[1]
        return m.run(steps, x, xd0.copy(), P)[at] / m.resolution, x

    def _fit(self, segment: tuple[np.ndarray, ...], z: np.ndarray, y: np.ndarray, x_end: np.ndarray
             ) -> tuple[np.ndarray, tuple[float, float], np.ndarray] | None:
        """Gauss-Newton on (torque, start speed) over one segment from the running estimate: the step,
        the torque's standard error and the part of it the sensors' counts set (nan, nan: held by static
        friction), d end state / d step; None when the segment says nothing."""
        n = 1 if self._vel is None else 2
        h = np.array([NUDGE_NM, NUDGE_RAD_S][:n])
        delta = np.zeros(n)
        if not (np.all(np.isfinite(z)) and np.all(np.isfinite(y))):
            return None
        for _ in range(MAX_ITER):
            phi = np.empty((y.size, n))
            dx = np.empty((x_end.size, n))
            for j in range(n):
                d = delta.copy()
                d[j] += h[j]
                yj, xj = self._run(segment, d)
                phi[:, j] = (yj - y).ravel() / h[j]
                dx[:, j] = (xj - x_end) / h[j]
            if not np.any(phi[:, 0]):  # the prediction does not move with the torque: held by static friction
                if float(np.max(np.abs(z - y))) <= UNSTICK_COUNTS:  # ... and so was the rig, as far as it can tell
                    return np.zeros(n), (math.nan, math.nan), dx
                start = self._unstick(segment, z, y)  # the rig moved: a torque beyond the band
                if start is None:
                    return None
                delta[0] = start
                y, x_end = self._run(segment, delta)
                continue
            e = (z - y).ravel()
            R = phi.T @ phi
            if not np.all(np.isfinite(R)) or np.linalg.cond(R) > 1e12:
                return None
            step = np.linalg.solve(R, phi.T @ e)
            delta += step
            y, x_end = self._run(segment, delta)
            if abs(step[0]) < ITER_TOL_NM:
                break
        if self._held_at(segment, delta, y):
            return delta, (math.nan, math.nan), dx
        r = (z - y).ravel()
        dof = max(r.size - n, 1)
        sd = math.sqrt(float(np.linalg.inv(R)[0, 0]) * float(r @ r) / dof)
        # a reading is known to within its count: a torque that moves no sample by a count's standard deviation
        # (1/sqrt 12) is not seen, however well the counts fit (a joint pressed against a stiff stop)
        floor = 1.0 / (math.sqrt(12.0) * float(np.max(np.abs(phi[:, 0]))))
        return delta, (max(sd, floor), floor), dx

    def _unstick(self, segment: tuple[np.ndarray, ...], z: np.ndarray, y: np.ndarray) -> float | None:
        """The change of the torque, either way, growing from the nudge by threefold steps, that first lets the
        model's joint move (its prediction by half a count), the better fitting way; None: none does."""
        for k in range(1, UNSTICK_STEPS + 1):
            tried = []
            for sign in (1.0, -1.0):
                d = np.zeros(1 if self._vel is None else 2)
                d[0] = sign * NUDGE_NM * 3.0**k
                yk = self._run(segment, d)[0]
                if float(np.max(np.abs(yk - y))) > 0.5:
                    tried.append((float(np.sum((z - yk) ** 2)), d[0]))
            if tried:
                return min(tried)[1]
        return None

    def _held_at(self, segment: tuple[np.ndarray, ...], delta: np.ndarray, y: np.ndarray) -> bool:
        """The model at ``delta`` stands at the edge of a static friction band: a torque one way moves
        its prediction, the other way hardly at all (``HELD_SHARE``). Any torque inside the band fits the
        segment as well; the least squares found only its edge."""
        moves = []
        for sign in (1.0, -1.0):
            d = delta.copy()
            d[0] += sign * NUDGE_NM
            moves.append(float(np.max(np.abs(self._run(segment, d)[0] - y))))
        return min(moves) <= HELD_SHARE * max(moves)

    def window(self, start_s: float, end_s: float, sign: float) -> tuple[float, float]:
        """The mean torque toward a move's target (``sign``: +1 toward larger angles) over the segments
        whose middle lies in [start_s, end_s], and the half-width of its 95 % interval [N m]; nan when
        fewer than three of them say enough (``_seen``: the others take the value their neighbours in
        time give). The interval is the mean's over segments with independent errors, their spread the
        larger of their standard errors and the spread of second differences (which a torque changing
        smoothly from one segment to the next leaves out, unlike the plain spread), plus what no mean
        takes out: the static friction band of the held segments and the range the unseen may hold."""
        segs = [s for s in self.segments if start_s <= 0.5 * (s.t0_s + s.t1_s) <= end_s]
        v = sign * np.array([s.torque_nm for s in segs])
        sd = np.array([s.sd_nm for s in segs])
        held = np.array([s.held for s in segs], dtype=bool)
        seen = _seen(segs, v)
        if seen.sum() < 3:
            return math.nan, math.nan
        mid = np.array([0.5 * (s.t0_s + s.t1_s) for s in segs])
        # a segment the sensors say too little about may hold any torque the move showed: its share of the range
        unseen = float(np.sum(~seen)) / v.size * 0.5 * float(np.ptp(v[seen]))
        v = np.interp(mid, mid[seen], v[seen])
        fitted = seen & ~held
        spread = max(math.sqrt(float(np.mean(np.diff(v, 2) ** 2)) / 6.0),  # var(e[k+1] - 2 e[k] + e[k-1]) = 6 var(e)
                     math.sqrt(float(np.mean(sd[fitted] ** 2))) if fitted.any() else 0.0)
        # a held segment's torque lies anywhere in its band, the same way from one segment to the next: at most
        # the bands' half-widths (unknown: the window's widest known) over the window's share of held segments
        bands = sd[held]
        widest = float(np.max(bands[np.isfinite(bands)])) if np.isfinite(bands).any() else 0.0
        band = float(np.sum(np.where(np.isfinite(bands), bands, widest))) / v.size
        return float(v.mean()), float(stats.t.ppf(0.975, v.size - 2) * spread / math.sqrt(v.size)) + band + unseen

    def summary(self) -> dict[str, Any]:
        """What metadata.json says about the estimate (the twin's ``patient_torque``)."""
        tau = np.array([s.torque_nm for s in self.segments])
        return {"source": self.source, "segment_s": self.model.segment_samples * self.model.period_s,
                "segments": len(self.segments),
                "mean_nm": float(tau.mean()) if tau.size else None}


def _seen(segs: Sequence[TorqueSegment], v: np.ndarray) -> np.ndarray:
    """Which of a window's segments say enough: a held one (its balance), and a fitted one whose counts set
    its torque within ``UNSEEN_FACTOR`` of the window's median segment's, with a standard error within half
    the range the move showed or that factor of the median's (not: a joint stopping, pressed against a stop)."""
    held = np.array([s.held for s in segs], dtype=bool)
    sd = np.array([s.sd_nm for s in segs])
    floor = np.array([s.floor_nm for s in segs])
    seen = held.copy()
    fitted = ~held
    if fitted.sum() >= 3:
        worse = max(0.5 * float(np.ptp(v[fitted])), UNSEEN_FACTOR * float(np.median(sd[fitted])))
        seen |= fitted & (floor <= UNSEEN_FACTOR * np.median(floor[fitted])) & (sd <= worse)
    return seen


def move_torques(estimator: PatientTorqueEstimator, cycles: Sequence[Mapping[str, Any]], period_s: float,
                 move_s: float, direction: float) -> list[dict[str, Any]]:
    """Each cycle's figures (``session_cycles``) with the model's estimate of the patient's torque toward
    each move's target and its 95 % half-interval (``patient_torque_open_model_nm``, ``..._ci_nm``, and
    closing), what it uses (``patient_torque_model_source``) and where the sensor's figure comes from
    (``patient_torque_source``: "torque sensor", when the rig has one); ``direction`` +1 when opening
    raises the axis angle."""
    out = []
    for c in cycles:
        row: dict[str, Any] = dict(c)
        start = float(c["start_s"])
        for (a, b), key, sign in zip(move_windows(period_s, move_s), ("open", "close"), (direction, -direction),
                                     strict=True):
            mean, ci = estimator.window(start + a, start + b, sign)
            row[f"patient_torque_{key}_model_nm"], row[f"patient_torque_{key}_model_ci_nm"] = mean, ci
        row["patient_torque_model_source"] = estimator.source
        if math.isfinite(c.get("patient_torque_open_nm", math.nan)):
            row["patient_torque_source"] = "torque sensor"
        out.append(row)
    return out


def _velocity_state(model: TwinModel, velocity_signal: str) -> int | None:
    """The state the axis's velocity signal reads (the one it moves with most, one model step from the
    rest state), or None when the signal moves with none."""
    s = model.system
    x0 = s.x0.copy()
    u = {n: v for n, v in zip(s.input_names, model.inputs_of(0, 0, 0, {}), strict=True)}
    gain = np.zeros(x0.size)
    for i in range(x0.size):
        x = x0.copy()
        x[i] += NUDGE_RAD_S
        y = s.simulate(1, u, [velocity_signal], model.P, x, s.xd0.copy())[velocity_signal][0]
        y0 = s.simulate(1, u, [velocity_signal], model.P, x0.copy(), s.xd0.copy())[velocity_signal][0]
        gain[i] = abs(y - y0) / NUDGE_RAD_S
    return int(np.argmax(gain)) if gain.max() > 0.5 else None


def patient_torque_estimator(cfg: Any, binding: DeviceBinding, period_s: float, segment_s: float,
                             channels: Sequence[str] | None = None) -> PatientTorqueEstimator | None:
    """The estimate on this plant's primary axis (None: the twin's model has no load to put there)."""
    model = TwinModel(cfg, binding, period_s, segment_s, channels or None, smooth=True)
    names = list(model.system.diagram.param_names)
    if LOAD_PARAM not in names:
        return None
    ports = get_plant(cfg.plant).ports(cfg)
    held = []
    if ports.interaction is not None and ports.interaction[0] in model.system.input_names:
        held = [list(model.system.input_names).index(ports.interaction[0])]
    axis = ports.axes[0]
    vel = _velocity_state(model, axis.velocity)
    return PatientTorqueEstimator(model, names.index(LOAD_PARAM), vel, held, axis.torque, source_text(model, binding))


def source_text(model: TwinModel, binding: DeviceBinding) -> str:
    """What the estimate uses: "model + encoder", "model + encoder + contact_force_n" ... (an ADC channel
    by its signal's name)."""
    return " + ".join(["model", *("encoder" if c == binding.angle_output else c for c in model.channels)])
