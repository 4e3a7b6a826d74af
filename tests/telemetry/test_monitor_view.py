"""The monitor's model and screen, fed directly (no terminal, no zenoh)."""

from __future__ import annotations

import math

from rich.console import Console

from rehab_hil.protocol import Fault, Status
from rehab_hil.telemetry.codec import StateSample
from rehab_hil.telemetry.monitor_view import MonitorState, render, sparkline


class Clock:
    def __init__(self) -> None:
        self.t = 0.0

    def __call__(self) -> float:
        return self.t


def sample(i: int, **kw: object) -> StateSample:
    base = dict(host_time_s=i * 1e-3, time_s=i * 1e-3, has_sample=True, device_time_us=i * 1000, sample_index=i,
                encoder_count=i, adc0=600, adc1=0, duty0=2500, duty1=0, direction=0, status=Status.STREAMING,
                faults=0, cmd_seq_echo=i, rx_bad_frames=3, has_state=True, state_t_s=i * 1e-3,
                angle_rad=math.radians(i / 10), velocity_rad_s=0.0, analog=(1.5,), command_duty0=0.25,
                command_duty1=0.0, command_direction=0, command_enable=True, reference_deg=45.0, command_seq=i,
                temperature_c=30.0 + i / 100, safety="unknown")
    base.update(kw)
    return StateSample(**base)  # type: ignore[arg-type]


def text(m: MonitorState) -> str:
    console = Console(width=100, record=True, color_system=None)
    console.print(render(m))
    return console.export_text()


def test_sparkline_spans_lowest_to_highest_and_blanks_nan() -> None:
    assert sparkline([0, 1, 2, 3, 4, 5, 6, 7]) == "▁▂▃▄▅▆▇█"
    assert sparkline([1.0, float("nan"), 1.0]) == "▁ ▁"
    assert sparkline([]) == ""
    assert len(sparkline(range(200))) == 60


def test_the_screen_shows_values_names_and_rate() -> None:
    clock = Clock()
    m = MonitorState("r1", clock=clock)
    m.set_info({"plant": "finger_extensor", "firmware_version": "1.0.2", "analog_names": ["contact_force_n"]})
    m.on_alive("r1", True)
    for i in range(1000):
        clock.t = i * 1e-3
        m.on_sample(sample(i))
    m.on_stats({"loop": {"sample_gaps": 2, "link": {"frames_rx": 999}}, "telemetry": {"dropped": 0}})
    out = text(m)
    for want in ("rig r1 running", "finger_extensor", "firmware 1.0.2", "angle", "99.90 deg", "reference",
                 "contact_force_n", "1.500", "0.250", "temperature est.", "40.0 C", "safety", "ok",
                 "loop.sample_gaps", "loop.link.frames_rx", "999", "telemetry.dropped"):
        assert want in out, want
    assert math.isclose(m.rate_hz(), 1000.0, rel_tol=0.02)


def test_safety_state_prefers_the_latest_trip_then_device_faults() -> None:
    m = MonitorState("r1")
    assert m.safety_state() == "-"
    m.on_sample(sample(1))
    assert m.safety_state() == "ok"
    m.on_sample(sample(2, faults=Fault.FORCE_LIMIT, status=Status.FAULT_LATCHED))
    assert m.safety_state().startswith("DEVICE FAULT") and "FORCE_LIMIT" in m.safety_state().upper()
    m.on_safety({"reason": "temperature", "detail": "91 C > 90 C"})
    assert m.safety_state() == "TRIPPED: temperature 91 C > 90 C"
    assert "TRIPPED: temperature" in text(m)


def test_a_gone_rig_and_no_samples_are_shown_as_such() -> None:
    m = MonitorState("r9")
    m.on_alive("r9", False)
    out = text(m)
    assert "rig r9 gone" in out and "no samples yet" in out


def test_cycles_without_a_sample_neither_blank_the_state_nor_count_in_the_rate() -> None:
    clock = Clock()
    m = MonitorState("r1", clock=clock)
    for i in range(1000):  # a 1 kHz rig whose loop also publishes a command-only record per sample
        clock.t = i * 1e-3
        m.on_sample(sample(i))
        m.on_sample(sample(i, has_sample=False, has_state=False, angle_rad=math.nan, velocity_rad_s=math.nan,
                           analog=()))
    out = text(m)
    assert "99.90 deg" in out and "1.500" in out  # the latest state, after a record without one
    assert math.isclose(m.rate_hz(), 1000.0, rel_tol=0.02)  # the rig's rate, not the records'
    assert "device samples received" in out and "1000 (1000 Hz)" in out
    assert m.samples == 2000 and m.device_samples == 1000
    assert all(math.isfinite(v) for k in ("angle", "analog") for v in m.trends[k])  # no blank in the trends
