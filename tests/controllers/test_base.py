"""Controllers declared like plants: claims come from the parts, names are checked where they are
written (the config's file and key), a controller that does not apply is refused before anything
moves, and the same parts run offline with the plant and alone on the rig."""

from __future__ import annotations

import numpy as np
import pytest

from rehab_hil.config import ConfigError
from rehab_hil.control.pid import PIDController
from rehab_hil.controllers import (
    DT,
    ControlContext,
    Controller,
    ControllerError,
    Plan,
    Reference,
    build_controller,
    closed_loop,
)
from rehab_hil.controllers.pid import limit_part
from rehab_hil.interfaces import Claims
from rehab_hil.loading import load_config
from rehab_hil.loop.controllers import ControllerRuntime
from rehab_hil.loop.estimation import State
from rehab_hil.testing import CONFIGS

from .conftest import with_text


def test_claims_are_derived_from_what_the_parts_read_and_write(fe, sma):
    assert build_controller(fe, "pid", Reference.step(fe), check=False).claims == \
        Claims(command=("motor_voltage_v",), state=("iris_angle_rad",))
    # the model-based SMA controller reads the encoder only (its temperature is its own observer's)
    ctl = build_controller(sma, "model_based", check=False)
    assert ctl.claims == Claims(command=("pwm_duty",), state=("theta_mcp_rad",))
    assert "contact_force_n" not in ctl.inputs


def test_a_part_reading_an_interface_the_plant_lacks_is_refused_naming_it(fe):
    ctx = ControlContext.of(fe)
    pid = PIDController("pid", connect={"reference": ctx.reference, "measurement": "contact_force_n",
                                        "dt_s": DT, "saturation": []},
                        rename={"command": "motor_voltage_v_demand"}, kp=1.0, ki=0.0, kd=0.0,
                        derivative_filter_s=0.0, output_min=-1.0, output_max=1.0)
    with pytest.raises(ControllerError, match=r"contact_force_n.*state interfaces: iris_angle_deg"):
        Controller("force_pid", ctx, Reference.step(fe), [Reference.step(fe).part(ctx.reference), pid,
                                                          limit_part(ctx, "motor_voltage_v_demand")],
                   sums=("motor_voltage_v_demand",))


def test_an_unknown_session_controller_is_refused_with_the_file_and_key(tmp_path):
    bad = with_text(CONFIGS / "sma_exoskeleton.toml", tmp_path / "x.toml",
                    replace=('controller = "model_based"', 'controller = "model_basd"'))
    with pytest.raises(ConfigError, match=r"x\.toml: rig\.session\.controller: unknown controller 'model_basd' "
                                          r"\(did you mean 'model_based'\?\)"):
        load_config(bad)


def test_a_typo_in_a_controller_table_is_reported_as_the_typo(tmp_path):
    bad = with_text(CONFIGS / "finger_extensor.toml", tmp_path / "x.toml",
                    replace=("[controllers.pid]                   # --controller pid: seed 002's position loop "
                             "on the encoder angle\nkp_per_deg", "[controllers.pid]\nkp_per_dge"))
    with pytest.raises(ConfigError, match=r"x\.toml: controllers\.pid\.kp_per_dge: unknown key \(did you mean "
                                          r"'kp_per_deg'\?\)"):
        load_config(bad)


def test_a_controller_that_does_not_apply_is_refused_at_configure(fe):
    with pytest.raises(ControllerError, match=r"'open_loop_map' does not apply to plant 'finger_extensor'.*signed"):
        build_controller(fe, "open_loop_map")
    with pytest.raises(ConfigError, match=r"controllers\.open_loop_map: missing table"):
        build_controller(load_config(CONFIGS / "tcp_finger.toml"), "open_loop_map")


def test_a_controller_that_would_trip_the_rig_is_refused_by_its_run_on_the_model(fe, tmp_path):
    """A hard push (6 V held 2 s each way) carries the iris out of its range of motion on the model:
    refused with the limit and the time, before a session starts."""
    hard = load_config(with_text(CONFIGS / "finger_extensor.toml", tmp_path / "hard.toml",
                                 replace=("effort = 1.2  ", "effort = 6.0  ")))
    with pytest.raises(ControllerError, match=r"'pulsed'.*run on the model it leaves the range of motion "
                                              r"\(iris_angle_deg .* deg outside -3..128 deg\) at \d+\.\d\d s"):
        build_controller(hard, "pulsed")


def test_a_reference_beyond_what_the_model_reaches_is_clipped_with_one_warning(sma):
    ctl = build_controller(sma, "model_based", check=False)
    assert len(ctl.notes) == 1 and "clipped (open_deg 37.5 -> 36.8)" in ctl.notes[0]
    assert ctl.reference.open_deg < 37.5 and ctl.reference.closed_deg == 0.0


def test_a_plan_past_its_horizon_repeats_its_last_period():
    plan = Plan(0.001, 0.003, {"u": np.arange(6.0)})
    assert [plan.index(k * 0.001) for k in range(10)] == [0, 1, 2, 3, 4, 5, 3, 4, 5, 3]
    assert list(plan.arrays(10)["u"]) == [0, 1, 2, 3, 4, 5, 3, 4, 5, 3]
    step = Plan(0.001, 0.001, {"u": np.arange(3.0)})  # a step's table holds its last value
    assert list(step.arrays(5)["u"]) == [0, 1, 2, 2, 2]


def test_the_rig_runtime_computes_what_the_offline_diagram_computes(fe):
    """One declaration, two worlds: fed the angles of the offline closed loop, the loop's runtime
    commands the same efforts, sample by sample."""
    ctl = build_controller(fe, "pid", Reference.step(fe), check=False)
    res = closed_loop(ctl, 0.5, outputs=["iris_velocity_rad_s"])
    rt = ControllerRuntime(ctl)
    scale = fe.motor.supply_v
    got = []
    for k, t in enumerate(res.t):
        cmd = rt(float(t), State(float(t), np.radians(res["iris_angle_deg"][k]),
                                 res["iris_velocity_rad_s"][k], {}))
        got.append(rt.actuator.effort(cmd))
    assert np.max(np.abs(np.array(got) - np.clip(res["motor_voltage_v"], -scale, scale))) < 1e-6 * scale


def test_the_runtime_takes_dt_from_device_time_so_a_bursty_loop_integrates_the_same(fe):
    """Behind a USB bridge the loop controls once per burst of ~2.2 samples: the PID must see the
    time that passed, so its integral after 1 s is the same whether stepped every 1 or 2.2 ms."""
    from rehab_hil.testing import pid_runtime

    every_ms, bursty = (pid_runtime(fe, 10.0, gains=(0.0, 1.0, 0.0, 0.0)) for _ in range(2))
    still = State(0.0, 0.0, 0.0, {})
    for k in range(1001):
        out_ms = every_ms(k * 0.001, still)
    for k in range(455):  # 0 .. 1.0 s in 2.2 ms steps
        out_burst = bursty(k * 0.0022, still)
    v_ms, v_burst = every_ms.actuator.effort(out_ms), bursty.actuator.effort(out_burst)
    assert v_ms == pytest.approx(10.0 * 1.0, rel=0.01)  # ki x error x time
    assert v_burst == pytest.approx(v_ms, rel=0.01)


def test_a_model_whose_angle_does_not_answer_the_effort_is_refused_for_model_based_control(tmp_path):
    """A 0.5 V supply cannot warm the wire to its transformation: the model has no inverse on the
    range, and the model-based controller says so instead of learning nothing."""
    weak = load_config(with_text(CONFIGS / "sma_exoskeleton.toml", tmp_path / "weak.toml",
                                 replace=("supply_voltage_v = 32.0", "supply_voltage_v = 0.5")))
    with pytest.raises(ControllerError, match=r"does not respond to pwm_duty.*no inverse on the range"):
        build_controller(weak, "model_based")


def test_integrating_ahead_after_the_write_commands_what_integrating_on_the_next_sample_does(sma):
    """The loop calls ``advance`` once a command is out, so the observer's integration over the
    next period is not between the next sample and its command. With samples lost (a step of 3
    periods) the rest of the interval is integrated on the call: the commands are those of a
    runtime that integrates everything on the call, sample for sample, and so is its observer's state."""
    from rehab_hil.service import assembly

    ahead, on_call = (assembly.build_controller(sma) for _ in range(2))
    assert ahead._x.size > 0  # an observer with continuous states: something to integrate
    period = assembly.period_s(sma)
    steps = [1] * 1500 + [3] + [1] * 500 + [2, 2] + [1] * 1000  # into the first bend (its ramp: 0-1.2 s)
    k, diff, drift, efforts = 0, 0.0, 0.0, []
    for n in steps:
        k += n
        t = k * period
        state = State(t, np.radians(5.0 * np.sin(2.0 * t)), 0.0, {"contact_force_n": 2.0})
        a, b = ahead(t, state), on_call(t, state)
        drift = max(drift, float(np.max(np.abs(ahead._x - on_call._x))))
        ahead.advance()
        efforts.append(ahead.actuator.effort(a))
        diff = max(diff, abs(ahead.actuator.effort(a) - on_call.actuator.effort(b)))
    assert np.ptp(efforts) > 0.05  # the controller drove ...
    assert np.max(np.abs(ahead._x - ahead._x0)) > 1.0  # ... and its observer moved: the comparison means something
    assert diff < 1e-6
    assert drift < 1e-6 * np.max(np.abs(ahead._x))
