"""The twin beside the loop: records in after the command is out, predictions, residuals and
events out, on a thread of its own.

``Twin`` is the whole computation and has no thread: ``feed`` takes the loop's sample records (the
same ``SampleRecord`` s the recorder gets), turns each sample into the model's inputs (what the device
says it applied) and measured channels, and every ``segment_s`` of samples runs the model
(``TwinModel``), the residual test (``ResidualMonitor``), the online interaction estimate and,
after a mismatch, the quick diagnosis. ``LiveTwin`` runs it off the hot path as one of the loop's
sinks (``loop.sinks.ThreadedSink``, named "twin"): the work happens while the loop waits for its
next sample, and gives the interpreter back every few records. A twin that falls behind drops
records from its queue (counted, reported) and never slows the loop; a twin that fails is reported
and the session goes on.

Outputs go to listeners (``TwinListener``, ``twin.outputs``): ``twin.csv`` beside ``run.csv``, and
the other sinks (MCAP and Foxglove ``/twin/prediction``, events on ``/rig/event``; zenoh
``rehab/<rig>/twin``).
"""

from __future__ import annotations

import math
import os
import time
from collections import deque
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any, Protocol

import numpy as np

from rehab_hil.config import TwinSection
from rehab_hil.interchange import Recording
from rehab_hil.interfaces import DeviceBinding
from rehab_hil.loop.records import SampleRecord
from rehab_hil.loop.sinks import Overflow, ThreadedSink
from rehab_hil.twin.interaction import Estimate, InteractionEstimator, default_estimates
from rehab_hil.twin.model import TwinModel, TwinSetupError, check_rate
from rehab_hil.twin.monitor import MismatchEvent, ResidualMonitor
from rehab_hil.twin.patient_torque import TORQUE_RUNS, patient_torque_estimator
from rehab_hil.twin.thermal import ThermalEstimator, ThermalEvent, thermal_quantities

__all__ = ["PREDICTION_EVERY", "LiveTwin", "Twin", "TwinListener", "patient_column"]

PREDICTION_EVERY = 10  # one prediction message per this many samples (100 Hz at 1 kHz): plots, not data
DEFAULT_THERMAL_WINDOW_S = 12.0  # the thermal estimate's window without a session cycle (the SMA's) [s]
HISTORY_S = 30.0  # how much of the session the twin keeps for a diagnosis
YIELD_EVERY = 32  # records taken between two releases of the interpreter


def patient_column(name: str) -> str:
    """The recorded column of an estimated parameter (``part.param`` -> ``patient_part_param``)."""
    return "patient_" + name.replace(".", "_")


class TwinListener(Protocol):
    def prediction(self, msg: dict[str, float]) -> None: ...

    def mismatch(self, event: MismatchEvent, final: bool) -> None: ...

    # optional: ``thermal(event: ThermalEvent)``, a thermal quantity beyond its interval (``twin.thermal``)


class Twin:
    """The model, its residual test and the interaction estimate, fed with the loop's records."""

    def __init__(self, cfg: Any, binding: DeviceBinding, period_s: float, settings: TwinSection | None = None,
                 out_dir: str | Path | None = None, listeners: Sequence[TwinListener] = (),
                 check_speed: bool = True, cycle_s: float | None = None) -> None:
        """``cycle_s``: the session's open-close period, the thermal estimate's default window."""
        self.settings = settings or TwinSection()
        self.cfg, self.binding, self.period_s = cfg, binding, period_s
        self.model = TwinModel(cfg, binding, period_s, self.settings.segment_s, self.settings.channels or None)
        self.monitor = ResidualMonitor(self.model.channels, self.model.resolution, self.settings.monitor())
        self.listeners = list(listeners)
        self.channels = self.model.channels
        names = self.settings.estimate or default_estimates(self.model)
        est_segment_s = self.settings.estimate_segment_s or self.settings.segment_s
        self.estimator = (InteractionEstimator(TwinModel(cfg, binding, period_s, est_segment_s,
                                                         self.settings.channels or None, smooth=True),
                                               names, self.settings.forgetting_s) if names else None)
        self.estimate_history: list[tuple[float, list[Estimate]]] = []  # (segment end, estimates)
        self.thermal = thermal_estimator(cfg, binding, period_s, self.settings, cycle_s)
        # the patient's torque on the joint (twin/patient_torque.py): its own smooth model, the estimate's segments
        self.patient_torque = (patient_torque_estimator(cfg, binding, period_s, est_segment_s,
                                                        self.settings.channels or None)
                               if self.settings.patient_torque else None)
        runs = 1 + (2 + len(names) if self.estimator is not None else 0) + (
            TORQUE_RUNS if self.patient_torque is not None else 0)
        self.rtf = check_rate(self.model, runs, self.settings.min_realtime_factor) if check_speed else math.nan
        n_in = len(self.model.system.input_names)
        # a block is the shortest of the models' segments: the estimates take one segment of their own
        # model at a time, and the monitor sums a longer segment over several blocks
        cap = min([self.model.segment_samples, *(e.model.segment_samples for e in (self.estimator, self.patient_torque)
                                                 if e is not None)])
        self._index = np.zeros(cap, dtype=np.int64)
        self._U = np.zeros((cap, n_in))
        self._Y = np.zeros((cap, len(self.channels)))
        self._n = 0
        self._last_t = -math.inf
        self._angle = self.channels.index(binding.angle_output) if binding.angle_output in self.channels else -1
        self._analog = [(k, c) for k, c in enumerate(self.channels) if k != self._angle]
        self._sq = np.zeros(len(self.channels))  # squared residuals since the last anchor
        self._sq_n = 0
        self._seg_start = 0.0
        keep = round(HISTORY_S / period_s)
        self.history: deque[tuple[np.ndarray, np.ndarray, np.ndarray]] = deque(maxlen=max(2, keep // cap + 2))
        self.anchors: deque[tuple[int, np.ndarray, np.ndarray]] = deque(maxlen=max(2, keep // cap + 2))
        self.samples = 0
        self.segments = 0
        self.busy_s = 0.0  # CPU time spent in the model, the test and the estimate
        self.diagnoses: list[MismatchEvent] = []
        self._to_diagnose: list[MismatchEvent] = []
        self.diagnose_fn: Callable[[MismatchEvent, Recording, np.ndarray, np.ndarray], None] | None = None
        self._csv_fd = -1
        self.csv_path: Path | None = None
        if out_dir is not None:
            self.csv_path = Path(out_dir) / "twin.csv"
            self._csv_fd = os.open(self.csv_path, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o644)
            cols = ["time_s", *(f"{c}_predicted" for c in self.channels), *(f"{c}_residual" for c in self.channels),
                    *(f"{c}_cusum_counts" for c in self.channels),
                    *(patient_column(n) for n in (self.estimator.names if self.estimator else ()))]
            os.write(self._csv_fd, (",".join(cols) + "\n").encode())

    # -- in ------------------------------------------------------------------------------------
    def feed(self, record: Any) -> None:
        """One sample record (a ``SampleRecord``, or a replayed row with its fields): buffered; a full
        segment is processed."""
        smp, st = record.sample, record.state
        if smp is None or st is None or record.time_s <= self._last_t:
            return
        self._last_t = record.time_s
        n = self._n
        self._index[n] = round(record.time_s / self.period_s)
        self._U[n] = self.model.inputs_of(smp.duty0, smp.duty1, smp.direction, st.analog)
        y = self._Y[n]
        if self._angle >= 0:
            y[self._angle] = st.angle_deg + self.model.encoder_centre_deg
        for k, c in self._analog:
            y[k] = st.analog.get(c, math.nan)
        self._n = n + 1
        self.samples += 1
        if self._n == self._index.size:
            self.process()

    def process(self) -> None:
        """Run the model over the buffered samples, test the residuals, write and publish."""
        n = self._n
        if n == 0:
            return
        t0 = time.thread_time()
        self._n = 0
        index, U, Y = self._index[:n].copy(), self._U[:n].copy(), self._Y[:n].copy()
        block = self.model.advance(index, U, Y)
        self.history.append((index, U, Y))
        if self.estimator is not None:
            self.estimator.update(index, U, Y)
            self.estimate_history.append((float(index[-1] * self.period_s), self.estimator.estimates()))
        if self.patient_torque is not None:
            self.patient_torque.update(index, U, Y)
        thermal_events = self.thermal.update(index, U, Y) if self.thermal is not None else []
        r = block.residual
        events: list[MismatchEvent] = []
        ends = set(np.flatnonzero(block.anchored).tolist())
        lo = 0
        for e in sorted(ends | {n - 1}):  # each anchored segment's end, then what is left of the block
            seg = r[lo:e + 1]
            self._sq += np.nansum(seg**2, axis=0)
            self._sq_n += seg.shape[0]
            lo = e + 1
            if e not in ends:
                continue
            rms = np.sqrt(self._sq / max(self._sq_n, 1))
            t_end = float(block.t_s[e])
            events += self.monitor.update(self._seg_start, t_end, rms)
            self.anchors.append((int(index[e]) + 1, self.model.x.copy(), self.model.xd.copy()))
            self._sq[:] = 0.0
            self._sq_n = 0
            self._seg_start = t_end
            self.segments += 1
        if events and self.estimator is not None:  # the rig changed: the estimate learns afresh from the change
            self.estimator.restart(min(ev.t_s for ev in events))
        self.busy_s += time.thread_time() - t0
        self._write(block)
        self._tell_thermal(thermal_events)
        for ev in events:
            for lst in self.listeners:
                lst.mismatch(ev, final=not self.settings.diagnose)
            if self.settings.diagnose:
                self._to_diagnose.append(ev)
        self._diagnose_due(float(block.t_s[-1]))

    # -- out -----------------------------------------------------------------------------------
    def _write(self, block: Any) -> None:
        g = self.monitor.statistic
        if self._csv_fd >= 0:
            est = np.array([e.value for e in self.estimate_history[-1][1]]) if self.estimate_history else np.zeros(0)
            cols = np.column_stack([block.t_s, block.predicted, block.residual,
                                    np.broadcast_to(g, (block.t_s.size, g.size)),
                                    np.broadcast_to(est, (block.t_s.size, est.size))])
            lines = []
            for k, row in enumerate(cols):
                lines.append(",".join(f"{v:.8g}" for v in row))
                if k % YIELD_EVERY == YIELD_EVERY - 1:
                    time.sleep(0)
            os.write(self._csv_fd, ("\n".join(lines) + "\n").encode())
        if self.listeners:
            ests = self.estimate_history[-1][1] if self.estimate_history else []
            for k in range(0, block.t_s.size, PREDICTION_EVERY):
                msg = {"time_s": float(block.t_s[k])}
                for j, c in enumerate(self.channels):
                    msg[f"{c}_measured"] = float(block.measured[k, j])
                    msg[f"{c}_predicted"] = float(block.predicted[k, j])
                    msg[f"{c}_residual"] = float(block.residual[k, j])
                    msg[f"{c}_cusum_counts"] = float(g[j])
                for e in ests:
                    msg[patient_column(e.name)] = e.value
                a = self._angle
                if a >= 0:  # outputs.GENERIC_TWIN_FIELDS
                    msg["angle_measured_deg"] = float(block.measured[k, a])
                    msg["angle_predicted_deg"] = float(block.predicted[k, a])
                    msg["angle_residual_deg"] = float(block.residual[k, a])
                msg["cusum_max_counts"] = float(g.max())
                for lst in self.listeners:
                    lst.prediction(msg)
            time.sleep(0)

    def _tell_thermal(self, events: list[ThermalEvent]) -> None:
        """Thermal events to the listeners that take them (``thermal``)."""
        for ev in events:
            for lst in self.listeners:
                fn = getattr(lst, "thermal", None)
                if fn is not None:
                    fn(ev)

    # -- diagnosis -----------------------------------------------------------------------------
    def _diagnose_due(self, now_s: float) -> None:
        """Hand a mismatch to the diagnosis once ``diagnose_window_s`` of data after its start is in."""
        if not self._to_diagnose or self.diagnose_fn is None:
            return
        for ev in list(self._to_diagnose):
            if now_s < ev.t_s + self.settings.diagnose_window_s:
                continue
            self._to_diagnose.remove(ev)
            window = self._event_window(ev)
            if window is not None:
                self.diagnose_fn(ev, *window)

    def take_pending(self, min_s: float) -> list[tuple[MismatchEvent, tuple[Recording, np.ndarray, np.ndarray]]]:
        """The mismatches still waiting for their full window (the session ended first), each with the
        window it has, when that is at least ``min_s`` long; they are no longer waited for."""
        out = []
        for ev in self._to_diagnose:
            window = self._event_window(ev)
            if window is not None and window[0].t[-1] - window[0].t[0] >= min_s:
                out.append((ev, window))
        self._to_diagnose = []
        return out

    def _event_window(self, ev: MismatchEvent) -> tuple[Recording, np.ndarray, np.ndarray] | None:
        """The diagnosis window of a mismatch: ``diagnose_window_s`` from its start, or what there is."""
        return self.window(ev.t_s, ev.t_s + self.settings.diagnose_window_s)

    def window(self, start_s: float, end_s: float) -> tuple[Recording, np.ndarray, np.ndarray] | None:
        """The session from the last anchor at or before ``start_s`` to ``end_s`` on the model's
        signals, and the model's state at its start (None when the history no longer has it)."""
        # a segment's anchor is taken after its last sample (index + 1), and an event's start is that
        # sample's time: the anchor at the start is the one at k0 + 1 (was k0: the window began a
        # segment early, and the change fitted over it was in force 0.25 s before it was)
        k0 = round(start_s / self.period_s) + 1
        start = [a for a in self.anchors if a[0] <= k0]
        if not start:
            return None
        i0, x0, xd0 = start[-1]
        i1 = round(end_s / self.period_s)
        idx = np.concatenate([h[0] for h in self.history])
        keep = (idx >= i0) & (idx <= i1)
        if keep.sum() < 10:
            return None
        U = np.concatenate([h[1] for h in self.history])[keep]
        Y = np.concatenate([h[2] for h in self.history])[keep]
        t = (idx[keep] - i0) * self.period_s
        signals = {n: U[:, j] for j, n in enumerate(self.model.system.input_names)}
        signals.update({c: Y[:, j] for j, c in enumerate(self.channels)})
        return Recording(t, signals, rig=True), x0, xd0

    def finish(self) -> None:
        """Process what is buffered (the thermal estimate's last part of a window too) and close the CSV."""
        self.process()
        if self.thermal is not None:
            self._tell_thermal(self.thermal.finish())
        if self._csv_fd >= 0:
            os.close(self._csv_fd)
            self._csv_fd = -1

    def patient(self, cycle_s: float | None = None) -> dict[str, Any]:
        """The interaction estimate per cycle (the running estimate at each cycle's end, ``cycle_s``
        apart) and per session (least squares over every segment since the session began, or since an
        abrupt change the estimate restarted at; the last running value and its interval beside it)."""
        if not self.estimate_history or self.estimator is None:
            return {}
        last_t, last = self.estimate_history[-1]
        T = cycle_s if cycle_s and cycle_s > 0 else max(last_t, self.period_s)
        cycles: list[dict[str, float]] = []
        k = 1
        for t, ests in self.estimate_history:
            if t + 1e-9 >= k * T:
                cycles.append({"index": k - 1, "t_end_s": round(t, 4), **{e.name: e.value for e in ests},
                               **{f"{e.name}_ci95": e.ci95 for e in ests}})
                k += 1
        since = self.estimator.session_start_s
        session = {s.name: {"value": s.value, "ci95": s.ci95, "final": e.value, "final_ci95": e.ci95,
                            "nominal": e.nominal, "since_s": since}
                   for s, e in zip(self.estimator.session_estimates(), last, strict=True)}
        return {"session": session, "cycles": cycles, "cycle_s": T, "forgetting_s": self.settings.forgetting_s}

    def summary(self) -> dict[str, Any]:
        """What metadata.json and the run summary say about the twin."""
        return {"channels": self.channels, "segment_s": self.settings.segment_s, "samples": self.samples,
                "segments": self.segments, "model_realtime_factor": self.rtf,
                "cpu_per_sample_us": 1e6 * self.busy_s / max(self.samples, 1),
                # None: the session ended before the normal level was learned (settle_s + learn_s)
                "normal_residual": {ch.name: ch.first_mu * ch.resolution if math.isfinite(ch.first_mu) else None
                                    for ch in self.monitor.channels},
                "thermal": self.thermal.summary() if self.thermal is not None else None,
                "patient_torque": self.patient_torque.summary() if self.patient_torque is not None else None}


class LiveTwin(ThreadedSink):
    """``Twin`` on its own thread, one of the loop's sinks ("twin"), fed after the write."""

    def __init__(self, twin: Twin, queue_size: int = 20_000, wait_when_full: bool = False) -> None:
        """``wait_when_full``: a full queue holds the loop up instead of dropping the record (a lockstep
        session, which runs as fast as it can and whose results must not depend on the machine)."""
        super().__init__("twin", queue_size, Overflow.WAIT if wait_when_full else Overflow.DROP, poll_s=0.05)
        self.twin = twin
        self._taken = 0
        self.start()

    def handle(self, record: Any) -> None:
        if type(record) is SampleRecord:  # commands, cycles, events and messages are not the twin's
            self.twin.feed(record)
            self._taken += 1
            if self._taken % YIELD_EVERY == 0:
                time.sleep(0)

    def release(self) -> None:
        """Finish the twin (its last segment, ``twin.csv``), unless it failed."""
        if self.error is None:
            self.twin.finish()


def normal_residual_text(normal: dict[str, float | None]) -> str:
    """``summary()["normal_residual"]`` in one line: each channel's level, or that it is still learning."""
    return ", ".join(f"{c} {v:.3g}" if v is not None else f"{c} still learning" for c, v in normal.items())


def thermal_estimator(cfg: Any, binding: DeviceBinding, period_s: float, settings: TwinSection,
                      cycle_s: float | None) -> ThermalEstimator | None:
    """The thermal estimate ``[twin] thermal`` asks for (default: every thermal quantity of the plant's
    model), on a smooth model of its own; None when there is none or it is turned off."""
    found = {q.key: q for q in thermal_quantities(cfg)}
    keys = list(found) if settings.thermal is None else settings.thermal
    unknown = [k for k in keys if k not in found]
    if unknown:
        raise TwinSetupError(f"[twin] thermal: {unknown[0]!r} is not a thermal quantity of the {cfg.plant} "
                             f"model (it has {', '.join(found) or 'none'})")
    if not keys:
        return None
    window = settings.thermal_window_s or cycle_s or DEFAULT_THERMAL_WINDOW_S
    model = TwinModel(cfg, binding, period_s, settings.segment_s, settings.channels or None, smooth=True)
    return ThermalEstimator(model, [found[k] for k in keys], cfg, window, settings.thermal_memory_s)
