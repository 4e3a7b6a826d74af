"""The rig contract (``on_configure``), the lifecycle states and ``open_rig``: a mismatched device or
claim is refused before anything moves; calls in the wrong state are refused with a clear error."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import pytest

from rehab_hil.controllers import controller_names
from rehab_hil.hardware import (
    Claims,
    ContractError,
    HardwareError,
    LifecycleState,
    SerialHardware,
    on_configure,
    open_rig,
)
from rehab_hil.loading import load_config
from rehab_hil.plants import get_plant
from rehab_hil.service import assembly
from rehab_hil.testing import inprocess_rig

CONFIGS = Path(__file__).resolve().parents[2] / "configs"
CONFIG = CONFIGS / "finger_extensor.toml"


@pytest.fixture(scope="module")
def cfg():
    return load_config(CONFIG)


@pytest.fixture(scope="module")
def binding(cfg):
    return get_plant(cfg.plant).device(cfg)


def pid_claims(cfg, binding) -> Claims:
    return assembly.build_controller(cfg, "pid", "step").claims


def test_a_matching_device_and_the_shipped_controllers_pass(cfg, binding) -> None:
    hw = inprocess_rig(CONFIG, configured=False)
    for name in controller_names():  # each one that applies to the plant (the others are refused at build)
        try:
            ctl = assembly.build_controller(cfg, name, "step")
        except assembly.ServiceSetupError:
            continue
        on_configure(binding, hw.info, ctl.claims)
    assert pid_claims(cfg, binding) == Claims(command=("motor_voltage_v",), state=("iris_angle_rad",))


def test_another_protocol_version_is_refused(cfg, binding) -> None:
    hw = inprocess_rig(CONFIG, configured=False, hello={"protocol_version": 2})
    with pytest.raises(ContractError, match=r"protocol v2, this host v1") as e:
        on_configure(binding, hw.info, pid_claims(cfg, binding))
    assert "\n" not in str(e.value)


def test_too_few_pwm_channels_or_adc_inputs_are_refused(cfg, binding) -> None:
    no_pwm = inprocess_rig(CONFIG, configured=False, hello={"n_pwm": 0})
    with pytest.raises(ContractError, match=r"motor_voltage_v needs PWM channel 0, the device has 0"):
        on_configure(binding, no_pwm.info, pid_claims(cfg, binding))
    no_adc = inprocess_rig(CONFIG, configured=False, hello={"n_adc": 0})
    with pytest.raises(ContractError, match=r"patient_torque_nm needs ADC input 0, the device has 0"):
        on_configure(binding, no_adc.info)


def test_the_device_adopts_the_bindings_encoder_resolution_so_hello_may_differ(binding) -> None:
    other = inprocess_rig(CONFIG, configured=False, hello={"encoder_counts_per_rev": 4096})
    on_configure(binding, other.info)  # an earlier session's encoder: CONFIGURE carries this one's
    unknown = inprocess_rig(CONFIG, configured=False, hello={"encoder_counts_per_rev": 0})
    on_configure(binding, unknown.info)  # 0: not told yet
    huge = dataclasses.replace(binding, encoder_counts_per_rev=70_000)
    with pytest.raises(ContractError, match=r"70000 encoder counts/rev do not fit CONFIGURE's 16-bit field"):
        on_configure(huge, unknown.info)


def test_a_claim_the_binding_does_not_provide_is_refused(binding) -> None:
    hw = inprocess_rig(CONFIG, configured=False)
    with pytest.raises(ContractError, match=r"command interface 'motor_voltag_v'.*did you mean 'motor_voltage_v'"):
        on_configure(binding, hw.info, Claims(command=("motor_voltag_v",)))
    with pytest.raises(ContractError, match=r"claims state interface 'theta_mcp_rad'.*provided: \['iris_angle_rad'"):
        on_configure(binding, hw.info, Claims(state=("theta_mcp_rad",)))
    with pytest.raises(ContractError, match=r"'motor_voltage_v' is claimed by two controllers"):
        on_configure(binding, hw.info, [Claims(command=("motor_voltage_v",))] * 2)


def test_no_hello_is_refused(binding) -> None:
    with pytest.raises(ContractError, match="no HELLO"):
        on_configure(binding, None)


def test_lifecycle_states_and_calls_in_the_wrong_state(cfg, binding) -> None:
    hw = inprocess_rig(CONFIG, configured=False)
    assert hw.state is LifecycleState.INACTIVE
    with pytest.raises(HardwareError, match=r"write_command: the hardware is inactive; call configure\(\) first"):
        hw.write_command(0.1)
    hw.configure(assembly.firmware_configure(cfg, binding))
    assert hw.state is LifecycleState.ACTIVE
    seq = hw.write_command(0.0)
    s = hw.read_sample()
    assert s is not None and s.cmd_seq_echo == seq and hw.pending_samples() == 0
    hw.close()
    assert hw.state is LifecycleState.FINALIZED
    with pytest.raises(HardwareError, match=r"read_sample: the hardware is finalized"):
        hw.read_sample()
    with pytest.raises(HardwareError, match=r"connect: the hardware is finalized"):
        hw.connect()


def test_deactivate_stops_the_in_process_device_streaming_and_driving(cfg, binding) -> None:
    """ACTIVE -> INACTIVE on the device's own logic: not streaming, PWM off, max duty 0, the
    session's limits kept; configure() activates again."""
    session = assembly.firmware_configure(cfg, binding)
    hw = inprocess_rig(CONFIG)
    hw.write_command(0.5)
    assert hw.read() is not None and hw.core.streaming and hw.core.duty != [0, 0]
    hw.deactivate()
    assert hw.state is LifecycleState.INACTIVE and not hw.core.streaming and hw.core.duty == [0, 0]
    assert hw.core.config == dataclasses.replace(session, sample_rate_hz=0, max_duty=0)
    with pytest.raises(HardwareError, match=r"write_command: the hardware is inactive; call configure\(\) first"):
        hw.write_command(0.5)
    hw.configure(session)
    hw.write_command(0.0)
    assert hw.state is LifecycleState.ACTIVE and hw.read() is not None
    hw.close()


def test_a_serial_hardware_before_connect_refuses_commands() -> None:
    hw = SerialHardware("/dev/null-not-opened")
    assert hw.state is LifecycleState.UNCONFIGURED
    with pytest.raises(HardwareError, match=r"write_command: the hardware is unconfigured; call connect\(\) first"):
        hw.write_command(0.1)
    with pytest.raises(HardwareError, match=r"configure: the hardware is unconfigured"):
        hw.configure(assembly.firmware_configure(load_config(CONFIG), get_plant("finger_extensor").device(
            load_config(CONFIG))))


def test_open_rig_refuses_lockstep_on_a_serial_path_and_unknown_ports(tmp_path: Path) -> None:
    with pytest.raises(HardwareError, match="lockstep is a mode of the simulated devices"), \
            open_rig(str(tmp_path / "tty"), CONFIG, lockstep=True):
        pass
    with pytest.raises(HardwareError, match="cannot open"), open_rig(str(tmp_path / "tty"), CONFIG,
                                                                     connect_timeout_s=0.1):
        pass


def test_open_rig_inprocess_runs_the_plant_in_lockstep(cfg, binding) -> None:
    with open_rig("inprocess", CONFIG) as hw:
        assert hw.state is LifecycleState.INACTIVE and hw.info is not None
        hw.configure(assembly.firmware_configure(cfg, binding))
        counts = []
        for _ in range(200):
            hw.write_command(0.5)
            s = hw.read_sample()
            assert s is not None
            counts.append(s.encoder_count)
        assert counts[-1] > counts[0] + 50  # the motor turned the iris
        assert hw.stats.samples == 200 and hw.stats.dropped_samples == 0
    assert hw.state is LifecycleState.FINALIZED


@pytest.mark.slow
@pytest.mark.xdist_group("sim_device")
def test_open_rig_sim_connects_to_the_python_device_on_a_pty(cfg, binding) -> None:
    with open_rig("sim", CONFIG, lockstep=True, write_timeout_s=2.0, connect_timeout_s=10.0) as hw:
        assert isinstance(hw, SerialHardware) and hw.port.startswith("/dev/")
        on_configure(binding, hw.info, pid_claims(cfg, binding))  # the real device fits its plant
        hw.configure(assembly.firmware_configure(cfg, binding), timeout=10.0)
        hw.discard_pending()
        seq = hw.write_command(0.0)
        s = hw.read_sample(timeout=10.0)
        assert s is not None and s.cmd_seq_echo == seq


def test_rehab_hil_run_on_the_inprocess_device(capsys: pytest.CaptureFixture[str]) -> None:
    from rehab_hil.cli import main

    code = main(["run", "--config", str(CONFIG), "--device", "inprocess", "--controller", "pid", "--reference", "step",
                 "--duration", "0.5",
                 "--no-display"])
    assert code == 0, capsys.readouterr()
    out = capsys.readouterr().out
    assert "duration reached" in out and "device PWM off at end" in out
