"""Encoder zero, direction and homing (issue 15 item 5) on the Python simulated device and the firmware
in simavr, both on a pty in virtual time (lockstep: the same result on a loaded machine), plus the
in-process device for the CLI and the no-stop case.

The rig: the Finger Extensor with a closed mechanical stop at -8 deg (``[iris] closed_stop_deg``, the
``HardStop`` model part) and its encoder wired backwards (``[encoder] direction = -1``): the plant's
counts fall as the iris opens, and the host, told so by the same config, reads positive angles."""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

from rehab_hil.cli import main
from rehab_hil.hardware import HardwareError, SerialHardware, on_configure
from rehab_hil.loading import load_config
from rehab_hil.loop.estimation import Estimator
from rehab_hil.plants import get_plant
from rehab_hil.protocol import Sample
from rehab_hil.service import assembly
from rehab_hil.service.homing import home, home_count, home_current, home_hard_stop
from rehab_hil.testing import inprocess_rig

from .conftest import CONFIG, avr_skip_reason

pytestmark = [pytest.mark.slow, pytest.mark.timeout(240), pytest.mark.xdist_group("sim_devices")]

STOP_DEG = -8.0


def _rig_config(tmp: Path, direction: int = -1, stop: bool = True) -> Path:
    text = CONFIG.read_text()
    if stop:
        text = text.replace("stick_damping_nm_s_per_rad = 1.0 ", f"closed_stop_deg = {STOP_DEG}\n"
                            "stick_damping_nm_s_per_rad = 1.0 ", 1)
    text = text.replace("counts_per_rev = 2000 ", f"direction = {direction}\nhard_stop_deg = {STOP_DEG}\n"
                        "counts_per_rev = 2000 ", 1)
    text = text.replace("min_angle_deg = -5.0 ", "min_angle_deg = -12.0 ", 1)  # the stop inside the range
    path = tmp / f"fe_dir{direction}{'_stop' if stop else ''}.toml"
    path.write_text(text)
    return path


@pytest.fixture(params=["python", "avr"])
def device(request: pytest.FixtureRequest, tmp_path: Path) -> Iterator[tuple[Any, SerialHardware, Any, Any]]:
    """A freshly spawned lockstep device on the backwards-wired rig with a closed stop."""
    from rehab_hil.devices import spawn_device

    if request.param == "avr" and avr_skip_reason():
        pytest.skip(avr_skip_reason())
    path = _rig_config(tmp_path)
    cfg = load_config(path)
    binding = get_plant(cfg.plant).device(cfg)
    dev = spawn_device(request.param, path, clock="lockstep")
    hw = SerialHardware(dev.port, write_timeout_s=2.0, resend_s=None)
    try:
        hw.connect(timeout=10.0)
        yield dev, hw, cfg, binding
    finally:
        hw.close()
        dev.close()


def _drive(hw: SerialHardware, est: Estimator, duty: float, direction: int, n: int) -> Sample:
    """``n`` samples with one COMMAND each (the host loop's rhythm); returns the last."""
    s = None
    for _ in range(n):
        hw.write_command(duty, direction=direction)
        s = hw.read_sample(5.0)
        assert s is not None
        est.update(s.encoder_count, s.device_time_us, (s.adc0, s.adc1))
    assert s is not None
    return s


def test_a_backwards_encoder_reads_positive_flexion_then_hard_stop_homing_zeroes_at_the_stop(device) -> None:
    _, hw, cfg, binding = device
    on_configure(binding, hw.info)  # the device's HELLO (0 or 2000 counts/rev) is no mismatch any more
    session = assembly.firmware_configure(cfg, binding)
    assert session.encoder_counts_per_rev == 2000
    assert (session.enc_min, session.enc_max) == (-723, 67)  # -130..+12 deg, ends swapped by direction -1
    hw.configure(session, timeout=10.0)
    assert hw.connect().encoder_counts_per_rev == 2000  # adopted from CONFIGURE
    # open the iris: the wire counts fall, the host's angle (same config) rises
    hw.discard_pending()
    est = Estimator(binding)
    first = _drive(hw, est, 0.0, 0, 1)
    opened = _drive(hw, est, 0.15, 0, 150)
    hw.write_command(0.0, enable=False)
    assert opened.encoder_count < first.encoder_count - 50
    assert est.update(opened.encoder_count, opened.device_time_us, (0, 0)).angle_deg > 9.0
    # home against the closed stop, every firmware limit on (the rig's own 50 ms watchdog: in virtual
    # time a loaded machine cannot starve the link)
    result = home_hard_stop(hw, session, binding, STOP_DEG, duty=0.05, span_deg=140.0, timeout_s=10.0)
    assert result.count == home_count(binding, STOP_DEG) == 44  # -8 deg x 2000/360 x (-1)
    assert result.previous_count is not None and result.previous_count > opened.encoder_count + 20
    # the session's limits in the new frame: the iris rests at the stop, and reads -8 deg
    hw.configure(session, timeout=10.0)
    hw.discard_pending()
    est = Estimator(binding)
    rest = _drive(hw, est, 0.0, 0, 20)
    state = est.update(rest.encoder_count, rest.device_time_us, (rest.adc0, rest.adc1))
    assert rest.faults == 0 and abs(state.angle_deg - STOP_DEG) < 1.0


def test_current_pose_homing_gives_the_pose_its_count(device) -> None:
    _, hw, cfg, binding = device
    session = assembly.firmware_configure(cfg, binding)
    assert home_current(hw, session, binding, angle_deg=30.0).count == home_count(binding, 30.0) == -167
    hw.configure(session, timeout=10.0)
    hw.discard_pending()
    est = Estimator(binding)
    s = _drive(hw, est, 0.0, 0, 5)
    assert s.faults == 0 and abs(est.update(s.encoder_count, s.device_time_us, (0, 0)).angle_deg - 30.0) < 1.0


def test_run_homes_to_the_hard_stop_before_the_session(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    code = main(["run", "--config", str(_rig_config(tmp_path)), "--device", "inprocess", "--duration", "0.5",
                 "--no-display", "--home", "hard-stop"])
    out = capsys.readouterr().out
    assert code == 0, out
    assert "homed (hard-stop): encoder count 44" in out


def test_hard_stop_homing_without_a_stop_gives_up_and_needs_a_config_key(tmp_path: Path) -> None:
    path = _rig_config(tmp_path, direction=1, stop=False)
    cfg = load_config(path)
    binding = get_plant(cfg.plant).device(cfg)
    hw = inprocess_rig(path, configured=False)
    session = assembly.firmware_configure(cfg, binding)
    # the spring alone: the iris settles where motor and spring balance, far below -8 deg, and the
    # range of motion (the reachable span from the start) stops it: homing fails loudly, PWM off
    with pytest.raises(HardwareError, match=r"RANGE_OF_MOTION|no stall"):
        home_hard_stop(hw, session, binding, STOP_DEG, duty=0.05, span_deg=20.0, max_s=5.0)
    assert hw.core.duty == [0, 0]
    narrow = cfg.rig.limits.model_copy(update={"min_angle_deg": -5.0})  # the stop at -8 deg outside
    with pytest.raises(HardwareError, match="outside the range of motion"):
        home("hard-stop", hw, cfg.model_copy(update={"rig": cfg.rig.model_copy(update={"limits": narrow})}),
             binding, session)
    shipped = load_config(CONFIG)
    with pytest.raises(HardwareError, match=r"needs \[encoder\] hard_stop_deg"):
        home("hard-stop", inprocess_rig(CONFIG, configured=False), shipped, get_plant(shipped.plant).device(shipped),
             session)
