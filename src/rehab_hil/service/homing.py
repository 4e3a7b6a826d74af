"""Homing at session start (``rehab-hil run --home``): give the encoder count a known zero.

The Uno resets on every port open, so its count starts wherever the finger is. Two ways to fix it:

- ``current``: the user holds the finger at the home pose (``[encoder] home_angle_deg``, default 0)
  and confirms; SET_ENCODER gives that pose its count. Nothing moves (max_duty 0).
- ``hard-stop`` (a motor behind an H-bridge, the Finger Extensor): drive slowly towards the closed
  mechanical stop (``[encoder] hard_stop_deg``) at ``homing_duty``, detect the stall by the encoder
  not moving, stop, and give the stop its count. Every firmware limit stays active: max duty is the
  homing duty, the range of motion is the reachable span from the start pose, heating time,
  watchdog, force and e-stop are the session's.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable
from dataclasses import dataclass

from rehab_hil.hardware.interface import HardwareError, HardwareInterface, duty_units
from rehab_hil.interfaces import DeviceBinding
from rehab_hil.plants.sections import PlantConfig
from rehab_hil.protocol import Configure, Fault, Sample

__all__ = ["BACK_DEG", "HOME_MODES", "HomingResult", "home", "home_count", "home_current", "home_hard_stop"]

HOME_MODES = ("current", "hard-stop", "none")
HOMING_RATE_HZ = 100  # samples while homing: enough to see a stall, light on a slow link
WIDE = 1 << 30
BACK_DEG = 5.0  # range of motion allowed away from the stop while homing [deg]


@dataclass(frozen=True)
class HomingResult:
    """What homing did: the mode, the count given to the home pose, the count it had before (in the
    device's old frame) and how long the drive took in device time (hard-stop only)."""

    mode: str
    count: int
    previous_count: int | None = None
    drive_s: float = 0.0


def home_count(binding: DeviceBinding, angle_deg: float) -> int:
    """The encoder count of a joint angle under the binding's resolution and direction."""
    return round(binding.encoder_direction * angle_deg * binding.encoder_counts_per_rev / 360.0)


def _fresh(hw: HardwareInterface, timeout_s: float) -> Sample:
    """A sample taken after everything sent so far (a disabled COMMAND makes a lockstep device
    produce one; it arms the watchdog, which the next CONFIGURE disarms)."""
    hw.discard_pending()
    hw.write_command(0.0, enable=False)
    s = hw.read_sample(timeout_s)
    if s is None:
        raise HardwareError(f"homing: no sample within {timeout_s:.1f} s")
    return s


def home_current(hw: HardwareInterface, session: Configure, binding: DeviceBinding, angle_deg: float = 0.0,
                 timeout_s: float = 2.0) -> HomingResult:
    """Give the present pose the count of ``angle_deg``: deactivate (max duty 0: nothing can move) with
    the range of motion wide open (the old frame's cannot trip on the jump), then SET_ENCODER."""
    hw.deactivate(dataclasses.replace(session, enc_min=-WIDE, enc_max=WIDE), timeout=timeout_s)
    count = home_count(binding, angle_deg)
    hw.set_encoder(count, timeout=timeout_s)
    return HomingResult("current", count)


def _closing_channel(binding: DeviceBinding) -> int:
    """The PWM channel of the signed actuator (an H-bridge) that can drive towards the closed stop."""
    signed = [d.channel for d in binding.duty_inputs.values() if d.signed]
    if not signed:
        raise HardwareError(f"hard-stop homing needs a motor behind an H-bridge; the {binding.plant or 'plant'} "
                            "actuators cannot drive back (use --home current)")
    return signed[0]


def home_hard_stop(hw: HardwareInterface, session: Configure, binding: DeviceBinding, stop_deg: float,
                   duty: float, span_deg: float, stall_s: float = 0.25, stall_deg: float = 0.5,
                   max_s: float = 30.0, timeout_s: float = 2.0) -> HomingResult:
    """Drive towards decreasing angle (the channel's direction bit set: negative voltage) at ``duty``
    until the encoder moves less than ``stall_deg`` over ``stall_s`` of device time, stop, and give
    the stop the count of ``stop_deg``.

    ``span_deg``: how far the stop can be from the start pose (the joint's whole range); the range
    of motion allows that much towards the stop and ``BACK_DEG`` the other way (a joint still settling
    from its last move when homing starts, as a loaded host sees it). ``session`` is the
    session's CONFIGURE: its watchdog, heating time, force limit and e-stop apply while homing."""
    ch = _closing_channel(binding)
    cpr, d = binding.encoder_counts_per_rev, binding.encoder_direction
    per_deg = cpr / 360.0
    # where are we? (max duty 0: nothing moves; wide open: the old frame's range cannot trip)
    hw.configure(dataclasses.replace(session, sample_rate_hz=HOMING_RATE_HZ, max_duty=0, enc_min=-WIDE,
                                     enc_max=WIDE), timeout=timeout_s)
    c0 = _fresh(hw, timeout_s).encoder_count
    lo, hi = sorted((-d * span_deg * per_deg, d * BACK_DEG * per_deg))
    window = (c0 + math.floor(lo), c0 + math.ceil(hi))
    hw.configure(dataclasses.replace(session, sample_rate_hz=HOMING_RATE_HZ, max_duty=duty_units(duty),
                                     enc_min=window[0], enc_max=window[1]), timeout=timeout_s)
    hw.discard_pending()
    stall_counts = max(2, math.ceil(stall_deg * per_deg))
    history: list[tuple[int, int]] = []  # (device_time_us, count)
    t_first: int | None = None
    direction = 1 << ch
    duties = [0.0, 0.0]
    duties[ch] = duty
    hw.write_command(duties[0], duties[1], direction=direction)
    while True:
        s = hw.read_sample(timeout_s)
        if s is None:
            hw.write_command(0.0, enable=False)
            raise HardwareError(f"homing: no sample within {timeout_s:.1f} s")
        if s.faults:
            raise HardwareError(f"homing stopped by the firmware: {', '.join(Fault.names(s.faults))} "
                                f"(count {s.encoder_count}, range {window[0]}..{window[1]})")
        t_first = s.device_time_us if t_first is None else t_first
        elapsed_us = (s.device_time_us - t_first) & 0xFFFFFFFF
        history.append((elapsed_us, s.encoder_count))
        while history and elapsed_us - history[0][0] > stall_s * 1e6:
            old = history.pop(0)
            if abs(s.encoder_count - old[1]) <= stall_counts:  # still over a whole stall window
                hw.write_command(0.0, enable=False)
                return _zero_at_stop(hw, session, binding, stop_deg, s.encoder_count, window, elapsed_us, timeout_s)
        if elapsed_us > max_s * 1e6:
            hw.write_command(0.0, enable=False)
            raise HardwareError(f"homing: no stall within {max_s:.0f} s (count {c0} -> {s.encoder_count}): "
                                "no hard stop, or the encoder is not counting")
        hw.write_command(duties[0], duties[1], direction=direction)


def _zero_at_stop(hw: HardwareInterface, session: Configure, binding: DeviceBinding, stop_deg: float,
                  at: int, window: tuple[int, int], elapsed_us: int, timeout_s: float) -> HomingResult:
    """PWM is off; give the stop its count. The range of motion covers both frames while the count
    jumps (the old window and the same window moved by the jump), so it neither trips nor opens."""
    count = home_count(binding, stop_deg)
    shift = count - at
    both = dataclasses.replace(session, sample_rate_hz=HOMING_RATE_HZ, max_duty=0,
                               enc_min=min(window[0], window[0] + shift), enc_max=max(window[1], window[1] + shift))
    hw.configure(both, timeout=timeout_s)
    hw.set_encoder(count, timeout=timeout_s)
    s = _fresh(hw, timeout_s)
    if s.faults:
        raise HardwareError(f"homing: faults latched after zeroing: {', '.join(Fault.names(s.faults))}")
    return HomingResult("hard-stop", count, at, elapsed_us * 1e-6)


def home(mode: str, hw: HardwareInterface, cfg: PlantConfig, binding: DeviceBinding, session: Configure,
         confirm: Callable[[str], object] | None = None) -> HomingResult | None:
    """``rehab-hil run --home MODE``: ``confirm(prompt)`` waits for the user (current pose) or
    returns at once; None for ``none``. Raises ``HardwareError`` when homing cannot be done."""
    enc = getattr(cfg, "encoder", None)
    if mode == "none" or not binding.encoder_signal:
        return None
    if mode == "current":
        angle = enc.home_angle_deg if enc is not None else 0.0
        if confirm is not None:
            confirm(f"Hold the finger at the home pose ({angle:g} deg) and press Enter")
        return home_current(hw, session, binding, angle)
    if mode == "hard-stop":
        if enc is None or enc.hard_stop_deg is None:
            raise HardwareError("--home hard-stop needs [encoder] hard_stop_deg (the angle at the closed stop)")
        lim, host = cfg.rig.limits, cfg.rig.host_limits()
        if not host.min_angle_deg < enc.hard_stop_deg < host.max_angle_deg:
            raise HardwareError(f"[encoder] hard_stop_deg {enc.hard_stop_deg:g} is outside the range of motion "
                                f"[{host.min_angle_deg:g}, {host.max_angle_deg:g}] deg "
                                "([rig.limits] less the host margin): the session would trip at the stop")
        span = max(lim.max_angle_deg, enc.hard_stop_deg) - min(lim.min_angle_deg, enc.hard_stop_deg) + 5.0
        return home_hard_stop(hw, session, binding, enc.hard_stop_deg, enc.homing_duty, span)
    raise ValueError(f"home mode must be one of {HOME_MODES}, got {mode!r}")
