"""Every host timer runs on device time (sample index x period), not on loop cycles: over the
Uno's USB bridge samples arrive in bursts of 2-5 and the loop runs once per burst (issue 16)."""

from __future__ import annotations

import math
import random

import pytest

from rehab_hil.control.thermal import FirstOrderThermal
from rehab_hil.loop.controllers import Command
from rehab_hil.loop.estimation import State
from rehab_hil.loop.supervisor import Supervisor, SupervisorLimits
from rehab_hil.protocol import Status

DT = 0.001


def limits(**kw: float) -> SupervisorLimits:
    base = {"min_angle_deg": -5.0, "max_angle_deg": 120.0, "max_force_n": 10.0, "max_heating_s": 2.0,
            "max_temperature_c": 300.0, "link_loss_periods": 20, "max_duty": 1.0}
    base.update(kw)
    return SupervisorLimits(**base)


def state(t_s: float, **analog: float) -> State:
    return State(t_s, 0.0, 0.0, analog)


def bursts(seed: int, flush_s: float = 0.004096, jitter_s: float = 0.002):
    """Sample indices grouped as a 16U2 delivers them: whatever the device sent before each flush
    (every ~4.1 ms plus up to 2 ms of host scheduling jitter), so 2-6 samples a burst."""
    rng = random.Random(seed)
    t, k = 0.0, 0
    while True:
        t += flush_s + rng.uniform(0.0, jitter_s)
        n = int(t / DT) - k
        yield list(range(k, k + n))
        k += n


def run_bursty(sup: Supervisor, duty: float, seconds: float, seed: int = 1, **analog: float) -> float | None:
    """Drive ``duty`` from t=0; the loop sees each burst once. Returns the device time of the first trip."""
    for burst in bursts(seed):
        if not burst:
            continue
        for k in burst:
            sup.observe(k * DT, state(k * DT, **analog), 0, 0, arrival_s=None)
        sup.admit(burst[-1] * DT, Command((duty, 0.0), 0, True))
        if sup.tripped:
            return sup.events[0].t_s
        if burst[-1] * DT > seconds:
            return None
    return None


@pytest.mark.parametrize("seed", [1, 2, 3])
def test_heating_time_trips_within_2_percent_of_its_limit_under_bursty_arrival(seed: int) -> None:
    sup = Supervisor(limits(max_heating_s=2.0), DT)
    t_trip = run_bursty(sup, 0.5, 10.0, seed)
    assert sup.events[0].reason == "heating_time"
    assert t_trip == pytest.approx(2.0, rel=0.02)


def test_the_thermal_estimate_under_bursts_matches_one_sample_per_cycle() -> None:
    bursty = Supervisor(limits(max_heating_s=100.0), DT, thermal=FirstOrderThermal(23.0, 110.0, 1.0))
    run_bursty(bursty, 0.7, 3.0)
    t_end = bursty._thermal.t_s - DT  # the last command's time (the estimate runs to the end of its period)
    steady = FirstOrderThermal(23.0, 110.0, 1.0)
    for _ in range(round(t_end / DT) + 1):
        steady.step(0.7, DT)
    assert bursty.temperature_c == pytest.approx(steady.temperature_c, abs=0.3)
    # what counting cycles did (one period per loop cycle, one cycle per ~5 ms burst) lags far behind
    per_cycle = FirstOrderThermal(23.0, 110.0, 1.0)
    n_bursts = sum(1 for _, b in zip(range(10_000), bursts(1), strict=False) if b and b[-1] * DT <= t_end)
    for _ in range(n_bursts):
        per_cycle.step(0.7, DT)
    assert bursty.temperature_c - 23.0 > 2.0 * (per_cycle.temperature_c - 23.0)


def test_force_debounce_counts_device_time_a_burst_of_noise_passes_a_real_overload_trips() -> None:
    sup = Supervisor(limits(force_debounce_s=0.003), DT, ("contact_force_n",))
    for k in range(100):  # 2 noisy samples above the limit every 10
        f = 15.0 if k % 10 in (3, 4) else 1.0
        sup.observe(k * DT, state(k * DT, contact_force_n=f), 0)
    assert not sup.tripped
    for k in range(100, 103):
        sup.observe(k * DT, state(k * DT, contact_force_n=15.0), 0)
    assert [e.reason for e in sup.events] == ["contact_force"] and sup.events[0].t_s == pytest.approx(0.102)


def test_the_estop_status_bit_trips_estop_input_only_when_enabled() -> None:
    off = Supervisor(limits(), DT)
    off.observe(0.0, state(0.0), 0, Status.ESTOP_INPUT_ACTIVE)
    assert not off.tripped
    on = Supervisor(limits(), DT, estop_input=True)
    on.observe(0.0, state(0.0), 0, Status.STREAMING)
    assert not on.tripped
    on.observe(0.001, state(0.001), 0, Status.STREAMING | Status.ESTOP_INPUT_ACTIVE)
    assert [e.reason for e in on.events] == ["estop_input"]
    on.observe(0.002, state(0.002), 0, Status.STREAMING)  # released: still latched
    assert on.tripped and on.admit(0.002, Command((0.5, 0.0), 0, True)).duty == (0.0, 0.0)


def test_a_thermistor_trips_on_its_reading_and_on_a_lasting_disagreement_with_the_estimate() -> None:
    lim = limits(max_temperature_c=120.0, max_disagreement_c=20.0, disagreement_s=0.5, max_heating_s=100.0)
    hot = Supervisor(lim, DT, thermal=FirstOrderThermal(23.0, 200.0, 1.0), temperature_signal="wire_c")
    hot.observe(0.0, state(0.0, wire_c=121.0), 0)
    assert [e.reason for e in hot.events] == ["temperature"]
    broken = Supervisor(lim, DT, thermal=FirstOrderThermal(23.0, 200.0, 1.0), temperature_signal="wire_c")
    t_trip = run_bursty(broken, 0.5, 5.0, wire_c=23.0)  # heating, but the sensor stays at ambient
    assert [e.reason for e in broken.events] == ["temperature_disagreement"]
    # the estimate passes 43 C at t = -ln(1 - 20/100) = 0.223 s; +0.5 s of disagreement
    assert t_trip == pytest.approx(0.223 + 0.5, abs=0.02)


def test_link_loss_counts_host_time_since_the_last_sample_not_empty_waits() -> None:
    sup = Supervisor(limits(link_loss_periods=20), DT)
    sup.observe(0.0, state(0.0), 0, arrival_s=100.0)
    for i in range(50):  # many short empty waits (a bridge flushing every 4 ms): not a loss
        sup.no_sample(0.0, 100.0 + 0.0003 * i)
    assert not sup.tripped
    sup.no_sample(0.0, 100.0 + 0.0201)
    assert [e.reason for e in sup.events] == ["link_loss"]
    assert math.isclose(sup.limits.link_loss_periods * DT, 0.02)
