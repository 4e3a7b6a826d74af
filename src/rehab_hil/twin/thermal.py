"""Online estimate of the thermal quantities that drift from day to day and matter for control: the
room's temperature, the convection (heat-transfer coefficient) and the supply as the heating rate
sees it (issue 39).

A thermal actuator's angle is a function of its temperature (an SMA wire's transformation band, a
TCP coil's heat through its force), and its temperature of the heat balance

    m c dT/dt = P(duty, supply) - h A (T - T_ambient)       (seed 000 eq 12; seed 001 eq 1a)

None of these is measured on the rig: they show only through what the applied duty does to the
angle (and force) over seconds. The estimate is therefore an output-error fit over a window of the
session (by default one open-close cycle): the twin's own model, run on the estimate with the
applied inputs from the window's start and re-anchored on the measured angle every segment (the
multiple shooting of ``model.py``; the temperature is not anchored, it is carried through the whole
window), predicts every measured sample; Levenberg-Marquardt with finite-difference sensitivities
through the whole model (from the best two of seven starts: the angle is flat outside the wire's
band, and one descent can stop in a wrong valley) moves the estimate to the prediction error's least
squares, weighed against the previous window's estimate (a recursive, iterated least squares across
windows; the previous covariance grows by the forgetting factor exp(window / memory) between
windows, never beyond the prior). The window ``finish`` fits when a session ends inside one counts
if it is at least half a window. The 95 % interval
comes from the posterior covariance with each channel's residual variance, widened for the
correlation of neighbouring residuals (AR(1), lag-one autocorrelation rho: x (1 + rho) / (1 - rho)).

Each quantity is a config key (``sma.ambient_c`` ...), estimated relative to the config's value
(1 = the config) and acting on the model through diagram parameters (every part's parameter of the
same name and value: the SMA's thermal balance and its Tanaka wire share ``ambient_c``) or by
scaling a model input (the SMA's ``supply_voltage_v``; the TCP's ``power_w``, which is max_power_w x
duty). An ambient also moves the start state's temperature (the wire rests at the room's
temperature). When an estimate leaves its interval around the config value by more than a floor
that matters for control, a ``thermal_change`` event says so; ``ThermalEvent.updates`` are the
config keys and values a controller re-plans its feedforward on (``TwinRun.on_thermal_change``),
when the fit explains the window (``explains``: a difference that is not thermal, such as a wire's
pre-strain, is absorbed by the thermal quantities as well as they can, and leaves a large residual).
"""

from __future__ import annotations

import math
import time
from collections.abc import Mapping, Sequence
from dataclasses import asdict, dataclass, field
from typing import Any

import numpy as np

from rehab_hil.twin.interaction import resolve_parameters
from rehab_hil.twin.model import TwinModel, TwinSetupError
from rehab_hil.twin.thermal_fit import WindowFit, explains, grown_covariance, rms

__all__ = ["THERMAL_EVENT", "ThermalEstimator", "ThermalEvent", "ThermalQuantity", "thermal_event_text",
           "thermal_quantities"]

THERMAL_EVENT = "thermal_change"
SUBSAMPLE_S = 0.02  # the fit reads a sample every this long (neighbours carry the same information) [s]


@dataclass(frozen=True)
class ThermalQuantity:
    """One thermal quantity: its config key, what it changes in the model, its prior and its floor."""

    key: str  # the config key (dotted), e.g. "sma.ambient_c"
    label: str  # "ambient", "convection", "supply"
    prior_sd: float  # the prior's standard deviation, in the key's unit (how far a lab's day may take it)
    floor: float  # a change smaller than this does not matter for control, in the key's unit
    params: tuple[str, ...] = ()  # diagram parameters (part.param) scaled with it
    input: str | None = None  # ... or the model input scaled with it
    state: str | None = None  # a state that moves with it at rest (an absolute temperature: the ambient)


def thermal_quantities(cfg: Any) -> list[ThermalQuantity]:
    """The thermal quantities of a plant's model that the twin can estimate from its rig (none for a
    plant without a thermal actuator)."""
    if cfg.plant == "sma_exoskeleton":
        # seed 000 Table 5: T0 = 23 C, h1 = 300 W/(m^2 C), U = 32 V; priors: a lab's day (+-5 C, a
        # draft or still air +-30 %, a supply +-10 %); floors: what moves the bend by about a degree
        return [ThermalQuantity("sma.ambient_c", "ambient", 5.0, 1.0, params=("sma_thermal.ambient_c",),
                                state="sma_thermal.temperature_c"),
                ThermalQuantity("sma.h1_w_per_m2_c", "convection", 90.0, 15.0, params=("sma_thermal.h1_w_per_m2_c",)),
                ThermalQuantity("drive.supply_voltage_v", "supply", 3.2, 0.64, input="supply_voltage_v")]
    if cfg.plant == "tcp_finger":
        out = [ThermalQuantity("muscle.max_power_w", "supply", 0.15 * cfg.muscle.max_power_w,
                               0.03 * cfg.muscle.max_power_w, input="power_w")]
        # the room does not enter either model: Table 1's TFs are deviations from rest, and TF2 reads the
        # lumped model's temperature less the room's (tcp_finger._muscle); eq 1a's convection is a parameter
        if cfg.muscle.model == "lumped":
            out += [ThermalQuantity("muscle.lumped.convection_w_per_m2_k", "convection",
                                    0.3 * cfg.muscle.lumped.convection_w_per_m2_k,
                                    0.05 * cfg.muscle.lumped.convection_w_per_m2_k,
                                    params=("thermal.convection_w_per_m2_k",))]
        return out
    return []


def config_value(cfg: Any, key: str) -> float:
    """The value of a dotted config key."""
    obj = cfg
    for part in key.split("."):
        obj = getattr(obj, part)
    return float(obj)


@dataclass
class ThermalEvent:
    """A thermal quantity beyond its interval around the config's value."""

    t_s: float  # the end of the window that showed it (device time) [s]
    key: str
    label: str
    value: float  # the estimate, in the key's unit
    ci95: float  # the half-width of its 95 % interval
    config: float  # the config's value
    updates: dict[str, float] = field(default_factory=dict)  # every quantity beyond its interval now
    explained: bool = True  # the fitted quantities explain the window (``ThermalEstimator.explains``)
    residual_counts: list[float] = field(default_factory=list)  # per channel: RMS after the fit [counts]
    action: str = ""  # what the controller does about it (``TwinRun.on_thermal_change``), if anything
    kind: str = THERMAL_EVENT

    def as_dict(self) -> dict[str, Any]:
        return asdict(self)

    def text(self) -> str:
        """One line for the event channel and the summary."""
        return thermal_event_text(self.as_dict())


def thermal_event_text(ev: Mapping[str, Any], label: bool = True) -> str:
    """A thermal event (``ThermalEvent.as_dict``, as metadata.json keeps it) in one line: the estimate,
    and what the controller does about it, or why it is not told (the fit left the window unexplained)."""
    head = (f"{ev['label'] + ' ' if label else ''}{ev['key']} = {ev['value']:.4g} +/- {ev['ci95']:.2g} "
            f"(config {ev['config']:.4g}) at {ev['t_s']:.1f} s")
    if ev.get("explained", True):
        return f"{head}; {ev['action']}" if ev.get("action") else head
    rms = ", ".join(f"{r:.1f}" for r in ev.get("residual_counts", []))
    return (f"{head}; not explained by the thermal quantities alone ({rms} counts RMS left after the fit): "
            "another difference, the controller is not told")


class ThermalEstimator:
    """The windowed, recursive output-error fit of the thermal quantities; ``update`` per block of
    samples, ``estimates`` any time."""

    def __init__(self, model: TwinModel, quantities: Sequence[ThermalQuantity], cfg: Any, window_s: float,
                 memory_s: float) -> None:
        """``model``: a ``TwinModel`` of the estimator's own (smooth: a quantity moves the angle by less
        than a count over a segment)."""
        if not quantities:
            raise TwinSetupError("thermal estimate: no thermal quantity to estimate")
        self.model, self.quantities = model, list(quantities)
        self.config = np.array([config_value(cfg, q.key) for q in self.quantities])
        if np.any(self.config == 0.0):
            raise TwinSetupError("thermal estimate: a config value is 0; the estimate is relative to it")
        self.params = [self._param_index(q) for q in self.quantities]
        names = model.system.input_names
        self.inputs = [names.index(q.input) if q.input in names else -1 for q in self.quantities]
        states = model.system.diagram.state_names
        self.states = [states.index(q.state) if q.state in states else -1 for q in self.quantities]
        self.P0 = model.P.copy()
        self.window_samples = max(2, round(window_s / model.period_s))
        self.lam = math.exp(-window_s / memory_s)
        self.theta = np.ones(len(self.quantities))
        self.cov = np.diag((np.array([q.prior_sd for q in self.quantities]) / np.abs(self.config)) ** 2)
        self._prior_cov = self.cov.copy()
        self._blocks: list[tuple[np.ndarray, np.ndarray, np.ndarray]] = []
        self._start = model.snapshot()
        self._start_theta = self.theta.copy()
        self._n = 0
        self._beyond: set[str] = set()
        self.history: list[dict[str, Any]] = []  # per window: its end and the estimates
        self.events: list[ThermalEvent] = []
        self.windows = 0
        self.explained = True  # the last window's fit explained it
        self.residual_counts: list[float] = []  # the last window's RMS per channel after the fit [counts]
        self.busy_s = 0.0  # CPU time of the fits

    def _param_index(self, q: ThermalQuantity) -> list[int]:
        if not q.params:
            return []
        try:
            return [i for ix in resolve_parameters(self.model, q.params) for i in ix]
        except TwinSetupError as e:
            raise TwinSetupError(f"thermal estimate {q.key}: {e}") from None

    # -- in ------------------------------------------------------------------------------------
    def update(self, index: np.ndarray, U: np.ndarray, measured: np.ndarray) -> list[ThermalEvent]:
        """One block of samples (as ``TwinModel.advance`` takes them); a full window is fitted.
        Returns the new events."""
        self._blocks.append((index, U, measured))
        self._n += index.size
        if self._n < self.window_samples:
            return []
        return self._fit_buffered()

    def finish(self) -> list[ThermalEvent]:
        """The session ended: the part of a window it has is fitted too, when it is at least half a
        window long (a session that trips in its first cycle still says what it saw)."""
        if self._n < self.window_samples // 2:
            return []
        return self._fit_buffered()

    def _fit_buffered(self) -> list[ThermalEvent]:
        """Fit the blocks gathered so far as one window, and start gathering the next."""
        index, U, Y = (np.concatenate([b[k] for b in self._blocks]) for k in range(3))
        self._blocks, self._n = [], 0
        return self.fit_window(index, U, Y)

    def fit_window(self, index: np.ndarray, U: np.ndarray, Y: np.ndarray) -> list[ThermalEvent]:
        """Fit one window, carry the model to its end on the new estimate, judge the estimate."""
        t0 = time.thread_time()
        fit = self._fit(index, U, Y)
        if fit is not None:
            self.theta, self.cov, before, after = fit
            self.explained = explains(before, after)
            self.residual_counts = [round(float(r), 3) for r in after]
        self._run(self.theta, index, U, Y)  # the model at the window's end, as run on the estimate
        self._start, self._start_theta = self.model.snapshot(), self.theta.copy()
        self.windows += 1
        self.busy_s += time.thread_time() - t0
        t_end = float(index[-1] * self.model.period_s)
        self.history.append({"t_end_s": round(t_end, 3), "fitted": fit is not None, "explained": self.explained,
                             "residual_counts": self.residual_counts,
                             **{q.key: e["value"] for q, e in zip(self.quantities, self.estimates(), strict=True)}})
        return self._judge(t_end)

    # -- the model on an estimate ----------------------------------------------------------------
    def _run(self, theta: np.ndarray, index: np.ndarray, U: np.ndarray, Y: np.ndarray) -> np.ndarray:
        """The window's predicted samples (channel units) with the quantities at ``theta``, from the
        window's start (its temperature moved with the ambient); the model is left at the end."""
        m = self.model
        P = self.P0.copy()
        Uq = U.copy()
        m.restore(self._start)
        for j, th in enumerate(theta):
            P[self.params[j]] *= th
            if self.inputs[j] >= 0:
                Uq[:, self.inputs[j]] *= th
            if self.states[j] >= 0:
                m.x[self.states[j]] += self.config[j] * (th - self._start_theta[j])
        m.P = P
        try:
            return m.advance(index, Uq, Y).predicted
        finally:
            m.P = self.P0
            time.sleep(0)  # the interpreter back to the loop between two runs (a fit is ~100 of them)

    def _fit(self, index: np.ndarray, U: np.ndarray, Y: np.ndarray) -> tuple[np.ndarray, ...] | None:
        """The window's fit with the previous estimate as prior (``thermal_fit.WindowFit``): the new
        estimate, its covariance and each channel's RMS (counts) before and after, or None (too few
        finite samples)."""
        m = self.model
        keep = np.arange(0, index.size, max(1, round(SUBSAMPLE_S / m.period_s)))
        z = Y[keep] / m.resolution
        ok = np.isfinite(z)
        if ok.sum() < 10:
            return None
        prior = self.theta.copy()
        fit = WindowFit(lambda th: self._run(th, index, U, Y)[keep] / m.resolution, z, ok, prior,
                        np.linalg.inv(grown_covariance(self.cov, self.lam, self._prior_cov)))
        theta, y = fit.best()
        return theta, fit.covariance(theta, y), rms(z - fit.predict(prior)), rms(z - y)

    # -- out -----------------------------------------------------------------------------------
    def estimates(self) -> list[dict[str, Any]]:
        """Each quantity's estimate and 95 % interval in its key's unit, beside the config value."""
        sd = np.sqrt(np.maximum(np.diag(self.cov), 0.0))
        rows = zip(self.quantities, self.config, self.theta, sd, strict=True)
        return [{"key": q.key, "label": q.label, "value": float(v0 * th), "ci95": float(1.96 * abs(v0) * s),
                 "config": float(v0)} for q, v0, th, s in rows]

    def beyond(self) -> dict[str, float]:
        """The quantities now beyond their interval (and floor) around the config value: key -> estimate."""
        out = {}
        for q, e in zip(self.quantities, self.estimates(), strict=True):
            if abs(e["value"] - e["config"]) > max(e["ci95"], q.floor):
                out[q.key] = e["value"]
        return out

    def _judge(self, t_s: float) -> list[ThermalEvent]:
        """An event for each quantity that has left its interval since the last window."""
        now = self.beyond()
        new = []
        for q, e in zip(self.quantities, self.estimates(), strict=True):
            if q.key in now and q.key not in self._beyond:
                new.append(ThermalEvent(t_s, q.key, q.label, e["value"], e["ci95"], e["config"], dict(now),
                                        self.explained, list(self.residual_counts)))
        self._beyond = set(now)
        self.events.extend(new)
        return new

    def summary(self) -> dict[str, Any]:
        """What metadata.json's twin section says about the thermal estimate."""
        return {"estimates": {e["key"]: e for e in self.estimates()}, "windows": self.history,
                "window_s": self.window_samples * self.model.period_s, "events": [e.as_dict() for e in self.events],
                "cpu_s_per_window": self.busy_s / max(self.windows, 1)}
