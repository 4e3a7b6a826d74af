"""What ``rehab-hil monitor`` shows: a thread-safe model fed by zenoh callbacks and a rich renderer.

Kept apart from the CLI so tests can feed samples and check the rendered text without a terminal.
"""

from __future__ import annotations

import collections
import math
import threading
import time
from collections.abc import Iterable, Mapping
from typing import Any

from rich.console import Group
from rich.panel import Panel
from rich.table import Table
from rich.text import Text

from rehab_hil.protocol import DUTY_FULL, Fault, Status
from rehab_hil.telemetry.codec import StateSample

__all__ = ["MonitorState", "render", "sparkline"]

_BARS = "▁▂▃▄▅▆▇█"
TREND_POINTS = 60
TREND_PERIOD_S = 0.1  # one trend point per 100 ms: a 6 s window


def sparkline(values: Iterable[float], width: int = TREND_POINTS) -> str:
    """Unicode block sparkline of the last ``width`` finite values (blank for NaN)."""
    vals = list(values)[-width:]
    finite = [v for v in vals if math.isfinite(v)]
    if not finite:
        return ""
    lo, hi = min(finite), max(finite)
    span = hi - lo
    out = []
    for v in vals:
        if not math.isfinite(v):
            out.append(" ")
        else:
            out.append(_BARS[0 if span <= 0 else min(len(_BARS) - 1, int((v - lo) / span * len(_BARS)))])
    return "".join(out)


def _fmt(v: Any, unit: str = "", digits: int = 2) -> str:
    if v is None or (isinstance(v, float) and not math.isfinite(v)):
        return "-"
    if isinstance(v, float):
        return f"{v:.{digits}f}{(' ' + unit) if unit else ''}"
    return f"{v}{(' ' + unit) if unit else ''}"


class MonitorState:
    """Latest sample, rates, trends, stats, safety and liveliness of one rig (callbacks may run on any thread)."""

    def __init__(self, rig: str, clock: Any = time.monotonic) -> None:
        self.rig = rig
        self._clock = clock
        self._lock = threading.Lock()
        self.latest: StateSample | None = None
        self.latest_sample: StateSample | None = None  # latest cycle that carried a device SAMPLE
        self.latest_state: StateSample | None = None  # latest cycle that carried a state estimate
        self.samples = 0  # records received (a cycle without a device SAMPLE is a record too)
        self.device_samples = 0  # records that carried a device SAMPLE: the rig's own rate
        self.alive: bool | None = None
        self.info: dict[str, Any] = {}
        self.stats: dict[str, Any] = {}
        self.safety_events: collections.deque[dict[str, Any]] = collections.deque(maxlen=5)
        self._rate_marks: collections.deque[tuple[float, int]] = collections.deque(maxlen=64)
        self._next_trend = 0.0
        self.trends: dict[str, collections.deque[float]] = {
            k: collections.deque(maxlen=TREND_POINTS) for k in ("angle", "analog", "duty", "temperature")}

    # -- feeding (zenoh threads) --------------------------------------------------------------------
    def on_sample(self, s: StateSample) -> None:
        with self._lock:
            self.latest = s
            self.samples += 1
            if s.has_sample:
                self.latest_sample = s
                self.device_samples += 1
            if s.has_state:
                self.latest_state = s
            now = self._clock()
            if now >= self._next_trend:
                self._next_trend = now + TREND_PERIOD_S
                self._rate_marks.append((now, self.device_samples))
                st = self.latest_state
                self.trends["angle"].append(st.angle_deg if st is not None else math.nan)
                self.trends["analog"].append(st.analog[0] if st is not None and st.analog else math.nan)
                self.trends["duty"].append(s.command_duty0)
                self.trends["temperature"].append(s.temperature_c)

    def on_stats(self, msg: Mapping[str, Any]) -> None:
        with self._lock:
            self.stats = dict(msg)

    def on_safety(self, msg: Mapping[str, Any]) -> None:
        with self._lock:
            self.safety_events.append(dict(msg))

    def on_alive(self, rig: str, alive: bool) -> None:
        with self._lock:
            self.alive = alive

    def set_info(self, info: Mapping[str, Any] | None) -> None:
        with self._lock:
            self.info = dict(info or {})

    # -- derived ----------------------------------------------------------------------------------
    def rate_hz(self) -> float:
        """Device samples received per second over the last few seconds (NaN until two marks exist):
        the rig's sample rate, whatever cycles without a sample the loop also publishes."""
        with self._lock:
            marks = [m for m in self._rate_marks if m[0] >= self._clock() - 3.0]
        if len(marks) < 2 or marks[-1][0] <= marks[0][0]:
            return math.nan
        return (marks[-1][1] - marks[0][1]) / (marks[-1][0] - marks[0][0])

    def safety_state(self) -> str:
        """'ok', the latest safety event's reason, or what the device's fault bits say."""
        with self._lock:
            s, events = self.latest_sample, list(self.safety_events)
        if events:
            ev = events[-1]
            return f"TRIPPED: {ev.get('reason', ev.get('state', '?'))} {ev.get('detail', '')}".strip()
        if s is not None and (s.faults or s.status & Status.FAULT_LATCHED):
            return "DEVICE FAULT: " + ",".join(Fault.names(s.faults) or ["latched"])
        if s is not None and s.safety not in ("unknown", "ok"):
            return s.safety
        return "ok" if s is not None else "-"


def _flat(d: Mapping[str, Any], prefix: str = "") -> list[tuple[str, Any]]:
    out: list[tuple[str, Any]] = []
    for k, v in d.items():
        if isinstance(v, Mapping):
            out.extend(_flat(v, f"{prefix}{k}."))
        else:
            out.append((f"{prefix}{k}", v))
    return out


def render(m: MonitorState) -> Group:
    """The monitor screen: rig header, live values with trends, safety, loop/link/telemetry stats."""
    with m._lock:
        s, ss, st, info, stats = m.latest, m.latest_sample, m.latest_state, dict(m.info), dict(m.stats)
        trends = {k: list(v) for k, v in m.trends.items()}
        alive, samples, device_samples = m.alive, m.samples, m.device_samples
    status = {True: "[green]running", False: "[red]gone", None: "[yellow]waiting"}[alive]
    head = Text.from_markup(f"[bold]rig {m.rig}[/] {status}[/]  plant {info.get('plant', '-')}  "
                            f"firmware {info.get('firmware_version') or '-'}  "
                            f"protocol {info.get('device_protocol_version') or '-'}")
    live = Table(show_header=True, box=None, expand=False)
    live.add_column("signal")
    live.add_column("value", justify="right")
    live.add_column("trend (6 s)")
    names = info.get("analog_names") or ["analog0", "analog1"]
    if s is not None:
        # the state shown is the latest that has one: a cycle without a sample does not blank it
        live.add_row("angle", _fmt(st.angle_deg if st is not None else math.nan, "deg"), sparkline(trends["angle"]))
        live.add_row("reference", _fmt(s.reference_deg, "deg"), "")
        live.add_row("velocity", _fmt(st.velocity_rad_s if st is not None else math.nan, "rad/s"), "")
        for i, v in enumerate(st.analog if st is not None else s.analog):
            live.add_row(str(names[i] if i < len(names) else f"analog{i}"), _fmt(v, digits=3),
                         sparkline(trends["analog"]) if i == 0 else "")
        live.add_row("duty cmd 0/1", f"{_fmt(s.command_duty0, digits=3)} / {_fmt(s.command_duty1, digits=3)}",
                     sparkline(trends["duty"]))
        if ss is not None:
            live.add_row("duty applied 0/1", f"{ss.duty0 / DUTY_FULL:.3f} / {ss.duty1 / DUTY_FULL:.3f}", "")
        live.add_row("temperature est.", _fmt(s.temperature_c, "C", 1), sparkline(trends["temperature"]))
    else:
        live.add_row("no samples yet", "", "")
    safety = m.safety_state()
    style = "green" if safety == "ok" else ("red" if safety != "-" else "yellow")
    rates = Table(show_header=False, box=None)
    rates.add_row("safety", Text(safety, style=style))
    rates.add_row("device samples received", f"{device_samples} ({_fmt(m.rate_hz(), 'Hz', 0)})")
    rates.add_row("records received", str(samples))
    if ss is not None:
        rates.add_row("sample index / device bad frames", f"{ss.sample_index} / {ss.rx_bad_frames}")
    for k, v in _flat({k: stats[k] for k in ("loop", "telemetry") if k in stats}):
        rates.add_row(k, _fmt(v, digits=3) if isinstance(v, float) else str(v))
    return Group(head, Panel(live, title="live"), Panel(rates, title="safety, rates, loop and link"))
