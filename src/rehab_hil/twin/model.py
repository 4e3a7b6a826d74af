"""The plant model bound to the rig's samples: driven by the applied inputs, re-anchored to the
measured states.

The twin runs the same (augmented) diagram the discrepancy workflow replays (``Replay``: the
plant, the config's ``[[effects]]`` and every applicable library effect attached disabled), so the
quick diagnosis can switch a candidate on by editing the parameter vector. Its inputs are what
the device reports it applied (each SAMPLE carries the duties and direction bits in force at that
tick) and the constants of the config; an ADC that measures a plant input (the Finger Extensor's
patient torque) feeds that input. The model predicts every measured output; every
``segment_s`` the states a measured channel "is" (an encoder angle is the joint angle) are set
to the measurement, the others carried on: the workflow's multiple shooting, run forward in time
(``discrepancy/shooting.py``). The residual of a segment is what the model got wrong in
``segment_s`` from a correct start, so it does not drift on an integrating plant.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from rehab_hil.discrepancy.initial_state import matched_states
from rehab_hil.discrepancy.replay import Replay
from rehab_hil.interchange import Recording
from rehab_hil.interfaces import DeviceBinding
from rehab_hil.plants.registry import Plant, get_plant
from rehab_hil.protocol import DUTY_FULL
from rehab_hil.twin.reading import RigReading

__all__ = ["Block", "TwinModel", "TwinSetupError"]

ANCHOR_SAMPLES = 10  # the anchoring error is the mean over this many samples: sensor noise averages out
FD_STEP = 0.02  # finite-difference step on a state for the anchor gain (relative, and its floor): wider
# than an encoder count, whose quantised output has no slope over a smaller step


class TwinSetupError(ValueError):
    """The twin cannot run beside this rig (one line, said at start)."""


@dataclass
class Block:
    """One block of samples the twin has processed: time, measured and predicted channels."""

    t_s: np.ndarray  # device time of each sample [s]
    measured: np.ndarray  # samples x channels (channel units: deg, N, A ...)
    predicted: np.ndarray  # samples x channels
    anchored: np.ndarray  # bool per sample: the model was re-anchored after this sample

    @property
    def residual(self) -> np.ndarray:
        return self.measured - self.predicted


class TwinModel:
    """The (augmented) plant model stepped on blocks of rig samples, re-anchored every ``segment_s``."""

    def __init__(self, cfg: Any, binding: DeviceBinding, period_s: float, segment_s: float = 0.5,
                 channels: Sequence[str] | None = None, smooth: bool = False) -> None:
        """``smooth``: an encoder channel is read as the angle the encoder measures, not its whole
        counts (an estimate's finite differences need a prediction that moves with a parameter)."""
        self.cfg, self.binding, self.period_s = cfg, binding, period_s
        self.spec: type[Plant] = get_plant(cfg.plant)
        channels, self.adc_inputs = _measured(self.spec, cfg, binding, channels)
        self.replay = _bind(self.spec, cfg, channels)
        self.channels: list[str] = list(self.replay.channels)
        sys_ = self.replay.system
        self.system = sys_
        self.steps_per_sample = max(1, round(period_s / sys_.dt))
        if abs(self.steps_per_sample * sys_.dt - period_s) > 1e-9:
            raise TwinSetupError(f"model step {sys_.dt} s does not divide the sample period {period_s} s")
        self.segment_samples = max(1, round(segment_s / period_s))
        self.P = self.replay.nominal_params()[: self.replay.n_diagram_params].copy()
        self.reading = RigReading(binding, self.channels, sys_.diagram.parts, smooth)  # the rig's view of them
        self.resolution = self.reading.resolution
        self._slots = sys_.out_slots(self.reading.signals)
        self._ws = sys_.workspace()
        names = sys_.input_names
        self._duty = [(names.index(n), d) for n, d in binding.duty_inputs.items() if n in names]
        self._adc_in = [(names.index(n), n) for n in self.adc_inputs if n in names]
        self._u_const = np.zeros(len(names))
        for n, v in binding.constant_inputs.items():
            if n in names:
                self._u_const[names.index(n)] = v
        # an encoder reads floor(angle x counts per unit): the middle of the count is the unbiased angle
        self.encoder_centre_deg = 0.5 * binding.encoder_direction * 360.0 / binding.encoder_counts_per_rev
        self.reset()
        self.anchor_gain = self._anchor_gain()

    # -- set-up ------------------------------------------------------------------------------
    def reset(self) -> None:
        """Back to the config's rest state, not yet anchored."""
        s = self.system
        self.x, self.xd = s.x0.copy(), s.xd0.copy()
        self.anchored = False
        self._since_anchor = 0
        self._last_index = -1
        self._u_last = self._u_const.copy()
        self.last_correction = np.zeros(len(self.channels))  # per channel, at the last anchor (sensor units)

    def snapshot(self) -> tuple[Any, ...]:
        """Everything ``advance`` changes, copied: a fit can run the model over a window again and again
        from one start (``restore``)."""
        return (self.x.copy(), self.xd.copy(), self.anchored, self._since_anchor, self._last_index,
                self._u_last.copy(), self.last_correction.copy())

    def restore(self, snap: tuple[Any, ...]) -> None:
        """Back to a ``snapshot`` (its arrays copied again: the snapshot stays reusable)."""
        x, xd, self.anchored, self._since_anchor, self._last_index, u_last, corr = snap
        self.x, self.xd, self._u_last, self.last_correction = x.copy(), xd.copy(), u_last.copy(), corr.copy()

    def _anchor_gain(self) -> np.ndarray:
        """States x channels: a measured error -> the state correction (the states each channel
        is, found as ``initial_state`` finds them: the output Jacobian's dominant entry)."""
        C = self.output_jacobian(self.x, self.xd, self._u_const)
        K = np.zeros((self.x.size, len(self.channels)))
        matched = matched_states(C, range(C.shape[0]), tol=1e-12)
        if matched:
            chans = sorted(matched)
            states = sorted(set(matched.values()))
            K[np.ix_(states, chans)] = np.linalg.pinv(C[np.ix_(chans, states)])
        return K

    def output_jacobian(self, x: np.ndarray, xd: np.ndarray, u: np.ndarray) -> np.ndarray:
        """d outputs / d states at (x, xd) with inputs u (central differences of one model sample)."""
        C = np.zeros((len(self.channels), x.size))
        for i in range(x.size):
            h = max(FD_STEP * abs(x[i]), FD_STEP)
            xp, xm = x.copy(), x.copy()
            xp[i] += h
            xm[i] -= h
            C[:, i] = (self._outputs_at(xp, xd, u) - self._outputs_at(xm, xd, u)) / (2 * h)
        return C

    def _outputs_at(self, x: np.ndarray, xd: np.ndarray, u: np.ndarray) -> np.ndarray:
        s = self.system
        _, Y = s.run_arrays(x.copy(), xd.copy(), u[None, :].copy(), self.P, self._slots, self._ws)
        return self.sensed(Y)[0]

    def realtime_factor(self, seconds: float = 1.0) -> float:
        """Model seconds per wall second on this machine (a rest run of ``seconds``), for the check
        that the twin can keep up with the loop."""
        import time

        s = self.system
        n = max(1, round(seconds / s.dt))
        U = np.repeat(self._u_const[None, :], n, axis=0)
        self.run(U, s.x0.copy(), s.xd0.copy())  # the first call loads the kernel
        t0 = time.perf_counter()
        self.run(U, s.x0.copy(), s.xd0.copy())
        return n * s.dt / max(time.perf_counter() - t0, 1e-9)

    # -- the inputs of a sample ----------------------------------------------------------------
    @property
    def at_anchor(self) -> bool:
        """The model stands at an anchor point: the next ``segment_samples`` samples are one segment."""
        return self._since_anchor == 0

    def inputs_of(self, duty0: int, duty1: int, direction: int, analog: dict[str, float]) -> np.ndarray:
        """The model's external inputs while a sample's duties were applied."""
        u = self._u_const.copy()
        duty = (duty0 / DUTY_FULL, duty1 / DUTY_FULL)
        for i, d in self._duty:
            u[i] = d.effort(duty[d.channel], direction)
        for i, name in self._adc_in:
            u[i] = analog.get(name, 0.0)
        return u

    # -- stepping ------------------------------------------------------------------------------
    def run(self, U: np.ndarray, x: np.ndarray, xd: np.ndarray, P: np.ndarray | None = None) -> np.ndarray:
        """Channel outputs of the model steps ``U`` from (x, xd), advanced in place, as the rig reads them."""
        s = self.system
        _, Y = s.run_arrays(x, xd, U, self.P if P is None else P, self._slots, self._ws)
        return self.sensed(Y)

    def sensed(self, Y: np.ndarray) -> np.ndarray:
        """Model outputs as the rig reads them (in place; ``RigReading.sensed``)."""
        return self.reading.sensed(Y)

    def beyond_resolution(self, err: np.ndarray) -> np.ndarray:
        """The part of an error a sensor can vouch for (``RigReading.beyond_resolution``)."""
        return self.reading.beyond_resolution(err)

    def anchor(self, measured: np.ndarray, u: np.ndarray) -> None:
        """Set the matched states so the model's outputs equal ``measured`` (a few Newton steps)."""
        K = self.anchor_gain
        if not np.any(K):
            return
        for _ in range(2):
            err = np.nan_to_num(measured - self._outputs_at(self.x, self.xd, u))
            self.x += K @ err

    def plan(self, index: np.ndarray, U: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The model-step inputs that take the state from now through samples ``index`` (a gap holds
        the last input over it), and the step at which each sample is read. No state changes."""
        S = self.steps_per_sample
        m = index.size
        gaps = np.maximum(np.diff(np.concatenate([[self._last_index], index])) - 1, 0) * S
        rows = np.empty((2 * m, U.shape[1]))
        rows[0::2] = np.concatenate([self._u_last[None, :], U[:m - 1]])
        rows[1::2] = U
        counts = np.empty(2 * m, dtype=np.int64)
        counts[0::2], counts[1::2] = gaps, S
        steps = np.ascontiguousarray(np.repeat(rows, counts, axis=0))
        return steps, np.cumsum(counts)[0::2]  # a sample is read at the first step of its own input

    def advance(self, index: np.ndarray, U: np.ndarray, measured: np.ndarray) -> Block:
        """Predict ``len(index)`` samples (continued sample indices, gaps allowed; inputs per sample,
        measured channels per sample), re-anchoring at every ``segment_samples`` boundary. The
        model's state is at the instant of the next expected sample; a gap holds the last input."""
        n = index.size
        pred = np.empty((n, len(self.channels)))
        anchored = np.zeros(n, dtype=bool)
        if n == 0:
            return Block(np.zeros(0), measured.copy(), pred, anchored)
        if not self.anchored:
            self.anchor(measured[0], U[0])
            self.anchored = True
            self._last_index = int(index[0]) - 1
        k = 0
        while k < n:
            j = min(n, k + self.segment_samples - self._since_anchor)  # up to the next anchor point
            steps, at = self.plan(index[k:j], U[k:j])
            Y = self.run(steps, self.x, self.xd)
            pred[k:j] = Y[at]
            self._u_last = U[j - 1].copy()
            self._last_index = int(index[j - 1])
            self._since_anchor += j - k
            if self._since_anchor >= self.segment_samples:
                tail = slice(max(k, j - ANCHOR_SAMPLES), j)  # the error's mean over the segment's last samples
                d = measured[tail] - pred[tail]
                ok = np.isfinite(d)  # a channel whose tail samples were all lost is not corrected (no warning)
                err = np.where(ok, d, 0.0).sum(axis=0) / np.maximum(ok.sum(axis=0), 1)
                self.last_correction = self.beyond_resolution(err)
                self.x += self.anchor_gain @ self.last_correction
                anchored[j - 1] = True
                self._since_anchor = 0
            k = j
        return Block(index * self.period_s, measured.copy(), pred, anchored)


def _measured(spec: type[Plant], cfg: Any, binding: DeviceBinding,
              channels: Sequence[str] | None) -> tuple[list[str], list[str]]:
    """The channels the twin compares (by default every model output the rig measures; one it does
    not measure is refused) and the ADC signals that feed a plant input (a patient torque)."""
    measured = [binding.angle_output] if binding.encoder_signal else []
    measured += [a.signal for a in binding.adc]
    outputs = set(spec.outputs)
    ext = set(spec.external_inputs(cfg))
    adc_inputs = [a.signal for a in binding.adc if a.signal in ext and a.signal not in outputs]
    available = [c for c in measured if c in outputs]
    if channels is None:
        channels = available
    bad = [c for c in channels if c not in available]
    if bad:
        raise TwinSetupError(f"residual on {bad[0]!r}: the rig does not measure it (it measures "
                             f"{available or 'no model output'})")
    if not channels:
        raise TwinSetupError(f"plant {cfg.plant!r}: the rig measures none of the model's outputs")
    return list(channels), adc_inputs


def _bind(spec: type[Plant], cfg: Any, channels: list[str]) -> Replay:
    """The workflow's augmented diagram for this plant and these channels (a placeholder record
    gives ``Replay.build`` its channel list; the twin feeds its own inputs)."""
    t = np.arange(0.0, 2.5, 0.01)
    signals = {n: np.linspace(0.0, 1.0, t.size) for n in spec.external_inputs(cfg)}
    signals.update({c: np.zeros(t.size) for c in channels})
    try:
        return Replay.build(spec, cfg, Recording(t, signals), "<twin>", closed_loop=False)
    except ValueError as e:
        raise TwinSetupError(f"plant {cfg.plant!r}: {e}") from None


def check_rate(model: TwinModel, runs: int, margin: float) -> float:
    """The model's real-time factor; refused in one line when ``runs`` model runs per segment would
    not keep up with the loop with ``margin`` to spare (``[twin] min_realtime_factor``)."""
    rtf = model.realtime_factor()
    need = margin * runs
    if not math.isfinite(rtf) or rtf < need:
        raise TwinSetupError(f"the {model.cfg.plant} model runs {rtf:.0f}x real time here; the twin needs "
                             f"{need:g}x ({runs} model runs per segment x min_realtime_factor {margin:g}): "
                             "it cannot keep up with the loop (turn it off, estimate fewer parameters or "
                             "simplify the model)")
    return rtf
