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
``rehab/<rig>/twin``); ``twin.writing`` writes the CSV's rows and the prediction messages. The recent
session a diagnosis replays, and the mismatches waiting for it, are ``twin.history``.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any, Protocol

import numpy as np

from rehab_hil.config import TwinSection
from rehab_hil.interchange import Recording
from rehab_hil.interfaces import DeviceBinding
from rehab_hil.loop.records import SampleRecord
from rehab_hil.loop.sinks import Overflow, ThreadedSink
from rehab_hil.twin.history import SessionHistory, Window
from rehab_hil.twin.interaction import Estimate, InteractionEstimator, default_estimates, estimate_report
from rehab_hil.twin.model import TwinModel, TwinSetupError, check_rate
from rehab_hil.twin.monitor import MismatchEvent, ResidualMonitor
from rehab_hil.twin.patient_torque import TORQUE_RUNS, patient_torque_estimator
from rehab_hil.twin.thermal import ThermalEstimator, ThermalEvent, thermal_quantities
from rehab_hil.twin.writing import PREDICTION_EVERY, YIELD_EVERY, TwinCsv, patient_column, prediction_messages

__all__ = ["PREDICTION_EVERY", "LiveTwin", "Twin", "TwinListener", "patient_column"]

DEFAULT_THERMAL_WINDOW_S = 12.0  # the thermal estimate's window without a session cycle (the SMA's) [s]
HISTORY_S = 30.0  # how much of the session the twin keeps for a diagnosis


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
        self.recent = SessionHistory(period_s, self.model.system.input_names, self.channels, max(2, keep // cap + 2),
                                     self.settings.diagnose_window_s)  # kept for the diagnosis
        self.history, self.anchors = self.recent.blocks, self.recent.anchors  # the blocks and anchors it keeps
        self.samples = 0
        self.segments = 0
        self.busy_s = 0.0  # CPU time spent in the model, the test and the estimate
        self.diagnoses: list[MismatchEvent] = []
        self.diagnose_fn: Callable[[MismatchEvent, Recording, np.ndarray, np.ndarray], None] | None = None
        self._csv = (TwinCsv(out_dir, self.channels, self.estimator.names if self.estimator else ())
                     if out_dir is not None else None)
        self.csv_path: Path | None = self._csv.path if self._csv is not None else None

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
                self.recent.waiting.append(ev)
        self._diagnose_due(float(block.t_s[-1]))

    # -- out -----------------------------------------------------------------------------------
    def _write(self, block: Any) -> None:
        """The block's rows of ``twin.csv`` and its prediction messages to the listeners (``writing.py``)."""
        g = self.monitor.statistic
        ests = self.estimate_history[-1][1] if self.estimate_history else []
        if self._csv is not None:
            self._csv.write(block, g, np.array([e.value for e in ests]) if self.estimate_history else np.zeros(0))
        if self.listeners:
            for msg in prediction_messages(block, self.channels, g, ests, self._angle):
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
        if not self.recent.waiting or self.diagnose_fn is None:
            return
        for ev, window in self.recent.due(now_s):
            self.diagnose_fn(ev, *window)

    def take_pending(self, min_s: float) -> list[tuple[MismatchEvent, Window]]:
        """The mismatches still waiting for their full window (the session ended first), each with the
        window it has, when that is at least ``min_s`` long; they are no longer waited for."""
        return self.recent.take_pending(min_s)

    def window(self, start_s: float, end_s: float) -> Window | None:
        """The session from the last anchor at or before ``start_s`` to ``end_s`` on the model's
        signals, and the model's state at its start (None when the history no longer has it)."""
        return self.recent.window(start_s, end_s)

    def finish(self) -> None:
        """Process what is buffered (the thermal estimate's last part of a window too) and close the CSV."""
        self.process()
        if self.thermal is not None:
            self._tell_thermal(self.thermal.finish())
        if self._csv is not None:
            self._csv.close()

    def patient(self, cycle_s: float | None = None) -> dict[str, Any]:
        """The interaction estimate per cycle (the running estimate at each cycle's end, ``cycle_s``
        apart) and per session (least squares over every segment since the session began, or since an
        abrupt change the estimate restarted at; the last running value and its interval beside it)."""
        if not self.estimate_history or self.estimator is None:
            return {}
        T = cycle_s if cycle_s and cycle_s > 0 else max(self.estimate_history[-1][0], self.period_s)
        return {**estimate_report(self.estimator, self.estimate_history, T), "forgetting_s": self.settings.forgetting_s}

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
