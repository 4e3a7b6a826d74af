"""Unit behaviour of the loop parts that need no device: timer, estimation, controllers,
supervisor, thermal estimate, recorder and telemetry sink."""

from __future__ import annotations

import itertools
import math
import sys
import time

import numpy as np
import pytest

from rehab_hil.control.open_loop import DutyMap
from rehab_hil.control.thermal import FirstOrderThermal
from rehab_hil.controllers import Reference
from rehab_hil.interchange import read_csv
from rehab_hil.interfaces import AdcChannel
from rehab_hil.loop.controllers import Actuator, Command
from rehab_hil.loop.estimation import Estimator, State, adc_to_si, unwrap_delta
from rehab_hil.loop.recorder import Recorder, read_mcap
from rehab_hil.loop.records import SampleRecord
from rehab_hil.loop.stats import NullSink, QueueSink, TelemetrySink
from rehab_hil.loop.supervisor import Supervisor, SupervisorLimits
from rehab_hil.loop.timing import DeadlineTimer, realtime_setup, realtime_teardown
from rehab_hil.protocol import Fault, Sample


def limits(**kw):
    base = {"min_angle_deg": -5.0, "max_angle_deg": 120.0, "max_force_n": 10.0, "max_heating_s": 1.0,
            "max_temperature_c": 80.0, "link_loss_periods": 5, "max_duty": 0.8}
    base.update(kw)
    return SupervisorLimits(**base)


def state(angle_deg=0.0, **analog):
    return State(0.0, math.radians(angle_deg), 0.0, analog)


def test_timer_skips_overrun_deadlines_and_counts_them_instead_of_catching_up():
    timer = DeadlineTimer(0.002, capacity=100)
    timer.start()
    assert timer.wait() == 0
    time.sleep(0.0105)  # overrun by more than 4 periods
    k = timer.wait()
    assert k >= 5 and timer.stats.missed == k - 1
    assert timer.wait() == k + 1  # the next deadline follows, no burst of late cycles
    assert timer.stats.n == 3


def test_realtime_setup_reports_the_scheduler_it_got():
    before = sys.getswitchinterval()
    rep = realtime_setup()
    try:
        assert rep.gc_frozen
        assert rep.scheduler.startswith(("SCHED_FIFO", "SCHED_OTHER ("))
        assert sys.getswitchinterval() == pytest.approx(rep.switch_interval_s) and rep.switch_interval_s < before
    finally:
        realtime_teardown()
    assert sys.getswitchinterval() == before


def test_realtime_setup_puts_the_loops_other_threads_at_the_helper_nice_and_teardown_restores_it():
    """The other threads share the loop's GIL: none may sit descheduled holding it (docs/loop.md)."""
    import os
    import threading

    ready, done, tid = threading.Event(), threading.Event(), []
    th = threading.Thread(target=lambda: (tid.append(threading.get_native_id()), ready.set(), done.wait()))
    th.start()
    ready.wait()
    before = os.getpriority(os.PRIO_PROCESS, tid[0])
    try:
        realtime_setup(helper_nice=-20)
        try:
            if os.geteuid() == 0:  # CAP_SYS_NICE: the nice value moved
                assert os.getpriority(os.PRIO_PROCESS, tid[0]) == -20
            assert os.getpriority(os.PRIO_PROCESS, threading.get_native_id()) == before  # the loop's own: untouched
        finally:
            realtime_teardown()
        assert os.getpriority(os.PRIO_PROCESS, tid[0]) == before
    finally:
        done.set()
        th.join()


def test_the_estimator_unwraps_like_unwrap_delta_across_both_32_bit_wraps(binding):
    est, cpr = Estimator(binding), binding.encoder_counts_per_rev
    counts = [2**31 - 3, 2**31 + 2, 2**32 - 1, 4, -(2**31), 2**31 - 1]  # as a u32 and an i32 would show them
    times = [2**32 - 2000, 2**32 - 1000, 0, 1000, 2000, 3000]
    s = None
    for c, t in zip(counts, times, strict=True):
        s = est.update(c, t, (0,))
    total = sum(unwrap_delta(b, a) for a, b in itertools.pairwise(counts))
    assert s.angle_rad == pytest.approx((counts[0] + total) * 2 * math.pi / cpr * binding.encoder_direction)
    assert s.t_s == pytest.approx(5 * 1000e-6)


def test_unwrap_delta_crosses_the_32_bit_wrap():
    assert unwrap_delta(5, 2**32 - 3) == 8
    assert unwrap_delta(2**32 - 3, 5) == -8


def test_estimator_angle_velocity_and_calibration(binding):
    est = Estimator(binding, velocity_cutoff_hz=50.0)
    cpr = binding.encoder_counts_per_rev
    s = None
    for k in range(400):  # constant speed: 1 count per ms
        s = est.update(k, 1000 * k, (612, 0))
    assert s.angle_rad == pytest.approx(399 * 2 * math.pi / cpr)
    assert s.velocity_rad_s == pytest.approx(1000 * 2 * math.pi / cpr, rel=1e-3)
    ch = binding.adc[0]
    assert s.analog[ch.signal] == pytest.approx(adc_to_si(612, ch))
    assert adc_to_si(612, AdcChannel("x_n", 100.0, 512.0)) == pytest.approx(1.0)


def test_actuator_maps_signed_effort_to_duty_and_direction(binding):
    act = Actuator(binding)
    cmd = act.command(-0.5 * act.max_effort)
    assert cmd.duty[act.input.channel] == pytest.approx(0.5)
    assert cmd.direction == 1 << act.input.channel and cmd.enable


def test_the_duty_map_is_linear_between_seed_000_duty_bounds():
    p, y = np.array([0.4, 1.0, 0.0, 37.5]), np.zeros(1)

    def duty(angle_deg: float) -> float:
        DutyMap.output(0.0, np.zeros(0), np.zeros(0), np.array([angle_deg]), p, y)
        return float(y[0])

    assert duty(0.0) == 0.0
    assert duty(37.5) == pytest.approx(1.0)
    assert duty(18.75) == pytest.approx(0.7)
    assert duty(100.0) == pytest.approx(1.0)


def test_a_session_reference_runs_five_cycles_per_minute_from_a_rest_at_closed():
    ref = Reference("session", 0.0, 40.0, move_s=3.0, hold_open_s=3.0, hold_closed_s=3.0)
    t = np.arange(0.0, 60.0, 0.01)
    r = ref.values(t)
    rises = np.sum((r[1:] >= 39.99) & (r[:-1] < 39.99))
    assert rises == 5
    assert np.all(r[t < ref.first_open_s] == 0.0) and ref.first_open_s == 3.0


def test_supervisor_clamps_duty_and_latches_pwm_off_after_a_trip():
    sup = Supervisor(limits(), 0.001, ("contact_force_n",))
    assert sup.admit(0.0, Command((1.0, 0.0), 0, True)).duty == (0.8, 0.0)
    sup.observe(0.0, state(10.0, contact_force_n=12.0), 0)
    assert sup.events[0].reason == "contact_force"
    sup.observe(0.0, state(10.0, contact_force_n=0.0), 0)  # cause gone: still latched
    out = sup.admit(0.001, Command((0.5, 0.0), 0, True))
    assert out.duty == (0.0, 0.0) and not out.enable


@pytest.mark.parametrize(("reason", "act"), [
    ("range_of_motion", lambda s: s.observe(0.0, state(121.0), 0)),
    ("device_fault", lambda s: s.observe(0.0, state(0.0), Fault.WATCHDOG)),
    ("link_loss", lambda s: [s.no_sample(0.0) for _ in range(5)]),
    ("heating_time", lambda s: [s.admit(k * 0.001, Command((0.1, 0.0), 0, True)) for k in range(1001)]),
])
def test_supervisor_trips_on_each_check(reason, act):
    sup = Supervisor(limits(), 0.001)
    act(sup)
    assert [e.reason for e in sup.events] == [reason]


def test_link_loss_needs_n_consecutive_missing_samples():
    sup = Supervisor(limits(), 0.001)
    for _ in range(4):
        sup.no_sample(0.0)
    sup.observe(0.0, state(), 0)
    for _ in range(4):
        sup.no_sample(0.0)
    assert not sup.tripped


def test_thermal_estimate_approaches_the_duty_proportional_equilibrium():
    th = FirstOrderThermal(20.0, 100.0, 1.0)
    for _ in range(10_000):
        th.step(0.5, 0.001)
    assert th.temperature_c == pytest.approx(20.0 + 50.0 * (1 - math.exp(-10.0)), rel=1e-6)


def _sample(i):
    return Sample(device_time_us=1000 * i, sample_index=i, encoder_count=i, adc0=512, adc1=0, duty0=100, duty1=0,
                  direction=0, status=0, faults=0, cmd_seq_echo=i, rx_bad_frames=0)


def test_recording_read_while_running_holds_everything_up_to_the_last_flush(binding, tmp_path):
    rec = Recorder(tmp_path, binding, flush_s=0.05)
    try:
        est = Estimator(binding)
        for i in range(200):
            s = _sample(i)
            rec.offer(SampleRecord(float(i), i * 0.001, s, est.update(s.encoder_count, s.device_time_us, (512, 0)),
                             Command((0.01, 0.0), 0, True), i, 23.0))

        def mcap_indices() -> list[int]:  # the run has not ended: no close() yet
            return [m["sample_index"] for topic, _, m in read_mcap(rec.mcap_path) if topic == "/rig/sample"]

        deadline = time.monotonic() + 30.0  # a flush every 0.05 s; a busy machine delays the writer's thread
        while len(mcap_indices()) < 200 and time.monotonic() < deadline:  # the MCAP is flushed after the CSV
            time.sleep(0.05)
        assert mcap_indices() == list(range(200))
        assert list(read_csv(rec.csv_path)["sample_index"].astype(int)) == list(range(200))
    finally:
        rec.close()
    assert [m["sample_index"] for t, _, m in read_mcap(rec.mcap_path) if t == "/rig/sample"] == list(range(200))


def test_a_drained_recorder_counts_every_row_offered_before_it_and_the_csv_holds_them(binding, tmp_path):
    """The run's metadata reports ``rows`` after ``drain``: every record queued when the loop stopped
    is written and counted, however far behind the writer was (it has not been woken here at all)."""
    rec = Recorder(tmp_path, binding, flush_s=60.0)
    est = Estimator(binding)
    for i in range(3000):
        s = _sample(i)
        rec.offer(SampleRecord(float(i), i * 0.001, s, est.update(s.encoder_count, s.device_time_us, (512, 0)),
                         Command((0.01, 0.0), 0, True), i, 23.0))
    rec.drain()
    rows = rec.rows
    rec.close(summary={"rows": rows})
    assert rows == 3000 == read_csv(rec.csv_path).t.size


def test_telemetry_sinks_never_block_and_count_drops():
    assert isinstance(NullSink(), TelemetrySink)
    gate = []
    sink = QueueSink(lambda s: gate.append(s) or time.sleep(0.05), maxsize=2)
    accepted = sum(sink.offer(i) for i in range(50))
    assert sink.dropped == 50 - accepted and sink.dropped > 0
    sink.close()
    assert sink.delivered == accepted


def _drive(sup: Supervisor, duty: float, reference_deg: float, angle_deg: float, seconds: float,
           t: float = 0.0) -> float:
    """Send ``duty`` towards ``reference_deg`` for ``seconds`` from ``t`` while the encoder reads
    ``angle_deg``; returns the time reached."""
    from rehab_hil.loop.controllers import Command

    for _ in range(round(seconds / 0.001)):
        sup.admit(t, Command((duty, 0.0), 0, True, reference_deg))
        sup.observe(t, state(angle_deg), 0)
        t += 0.001
    return t


def test_a_frozen_encoder_while_driving_hard_far_from_the_reference_trips_stuck_sensor():
    sup = Supervisor(limits(max_heating_s=100.0, stuck_sensor_s=0.5, stuck_min_duty=0.3, stuck_min_error_deg=10.0,
                            stuck_min_motion_deg=1.0), 0.001)
    t = _drive(sup, 0.8, 60.0, 5.0, 0.45)
    assert not sup.tripped
    _drive(sup, 0.8, 60.0, 5.0, 0.1, t)
    assert [e.reason for e in sup.events] == ["stuck_sensor"]


def test_holding_at_the_reference_or_at_low_duty_never_trips_stuck_sensor():
    lim = limits(max_heating_s=100.0, stuck_sensor_s=0.5, stuck_min_duty=0.3, stuck_min_error_deg=10.0,
                 stuck_min_motion_deg=1.0)
    hold = Supervisor(lim, 0.001)
    _drive(hold, 0.9, 37.5, 36.0, 2.0)  # steady duty, steady angle, close to the reference: a hold
    gentle = Supervisor(lim, 0.001)
    _drive(gentle, 0.1, 60.0, 5.0, 2.0)  # far away but barely driving
    assert not hold.tripped and not gentle.tripped


def test_a_moving_encoder_keeps_resetting_the_stuck_timer():
    from rehab_hil.loop.controllers import Command

    sup = Supervisor(limits(max_heating_s=100.0, stuck_sensor_s=0.5, stuck_min_duty=0.3, stuck_min_error_deg=10.0,
                            stuck_min_motion_deg=1.0), 0.001)
    for k in range(2000):  # 2 s rising at 5 deg/s, always > 10 deg from the reference
        t = k * 0.001
        sup.admit(t, Command((0.8, 0.0), 0, True, 60.0))
        sup.observe(t, state(5.0 + 5.0 * t), 0)
    assert not sup.tripped
