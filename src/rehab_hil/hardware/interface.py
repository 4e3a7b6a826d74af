"""The host's view of a rig, in the spirit of ros2_control's hardware components.

Lifecycle (``LifecycleState``): UNCONFIGURED --``connect()`` (open the link, HELLO)--> INACTIVE
--``configure()`` (rate, watchdog, limits: ACK)--> ACTIVE (each cycle ``read()`` /
``write_command()``; ``estop()`` / ``clear()`` on faults) --``deactivate()`` (PWM off, streaming
stopped, limits kept: ACK)--> INACTIVE; any state --``close()``--> FINALIZED. A call made in the
wrong state raises ``HardwareError`` naming the state and the missing step.
Implementations: ``SerialHardware`` (any serial path, incl. the ptys of the simulated devices) and
``InProcessHardware`` (the device's firmware logic and a plant model in this process).
"""

from __future__ import annotations

import dataclasses
import enum
import math
from abc import ABC, abstractmethod
from collections import Counter, deque
from dataclasses import dataclass, field
from types import TracebackType
from typing import Any, NamedTuple

import numpy as np

from rehab_hil.protocol import DUTY_FULL, Ack, Clear, Configure, EStop, FaultReport, Hello, Message, Sample, SetEncoder

__all__ = ["Arrival", "HardwareError", "HardwareInterface", "LifecycleState", "LinkStats", "angle_limits_counts",
           "configure_from_config", "duty_units"]


class HardwareError(RuntimeError):
    """The device did not answer, refused a request, or the link broke."""


class LifecycleState(enum.Enum):
    """Where a ``HardwareInterface`` is in its lifecycle (ros2_control's node states)."""

    UNCONFIGURED = "unconfigured"  # created; the link is not open
    INACTIVE = "inactive"  # connected (the device's HELLO is known), not streaming: not configured yet, or deactivated
    ACTIVE = "active"  # configured: the device streams and takes commands
    FINALIZED = "finalized"  # closed; terminal

    @property
    def connected(self) -> bool:
        return self in (LifecycleState.INACTIVE, LifecycleState.ACTIVE)


class Arrival(NamedTuple):
    """A SAMPLE as the loop takes it (``HardwareInterface.read``): when it arrived and how many
    samples went missing just before it, with the sample, so no second look at the link is needed."""

    host_time_s: float  # perf_counter when its bytes were read from the link
    sample: Sample
    gap: int  # samples missing from sample_index just before this one (0 after a device restart)


# tuple.__new__ builds an Arrival without the Python-level __new__ namedtuple generates (as its
# _make does): half the cost, once per sample on the receive path
_new_arrival = tuple.__new__


_NEXT_STEP = {
    LifecycleState.UNCONFIGURED: "call connect() first",
    LifecycleState.INACTIVE: "call configure() first",
    LifecycleState.FINALIZED: "it was closed; open a new one",
}


@dataclass
class LinkStats:
    """Always-on link diagnostics: frames, dropped frames by kind, lost samples, command latency."""

    frames_rx: int = 0
    frames_tx: int = 0
    bad_frames: Counter[str] = field(default_factory=Counter)  # host-side decoder drops, by kind
    device_rx_bad_frames: int = 0  # the device's own count of dropped frames (last SAMPLE)
    samples: int = 0
    dropped_samples: int = 0  # gaps in sample_index
    reboots: int = 0  # device restarts: an unsolicited HELLO after the handshake, or sample_index going back
    request_resends: int = 0  # requests (CONFIGURE, CLEAR, ...) sent again for want of an ACK
    latencies_s: deque[float] = field(default_factory=lambda: deque(maxlen=100_000))  # command -> echo

    def latency_percentiles(self, q: tuple[float, ...] = (50.0, 99.0)) -> dict[str, float]:
        """Command -> echo latency percentiles in seconds (nan when none measured)."""
        if not self.latencies_s:
            return {f"p{p:g}": math.nan for p in q}
        arr = np.fromiter(self.latencies_s, float)
        return {f"p{p:g}": float(np.percentile(arr, p)) for p in q}

    def as_dict(self) -> dict[str, Any]:
        return {
            "frames_rx": self.frames_rx, "frames_tx": self.frames_tx, "bad_frames": dict(self.bad_frames),
            "device_rx_bad_frames": self.device_rx_bad_frames, "samples": self.samples,
            "dropped_samples": self.dropped_samples, "reboots": self.reboots, "request_resends": self.request_resends,
            **{f"latency_{k}_s": v for k, v in self.latency_percentiles().items()},
        }


def duty_units(duty: float) -> int:
    """Duty 0..1 -> protocol duty units 0..10000 (clipped)."""
    if not math.isfinite(duty):
        raise ValueError(f"duty must be finite, got {duty!r}")
    return round(min(max(duty, 0.0), 1.0) * DUTY_FULL)


def angle_limits_counts(min_deg: float, max_deg: float, encoder_counts_per_rev: int,
                        direction: int = 1) -> tuple[int, int]:
    """An angle range [deg] as the firmware's (enc_min, enc_max) counts, rounded outwards; with
    ``direction`` -1 the counts fall as the angle rises, so the ends swap."""
    per_deg = direction * encoder_counts_per_rev / 360.0
    lo, hi = sorted((min_deg * per_deg, max_deg * per_deg))
    return math.floor(lo), math.ceil(hi)


def configure_from_config(cfg: Any, encoder_counts_per_rev: int, force_limit_counts: int = 1023,
                          estop_input: bool = False, encoder_direction: int = 1) -> Configure:
    """The CONFIGURE for a validated plant config: rate, watchdog, the ``[rig.limits]`` and the
    encoder's counts per revolution (the device adopts it and reports it in HELLO).

    Angles become encoder counts with ``encoder_counts_per_rev`` and ``encoder_direction``; the force
    limit in ADC counts depends on the sensor calibration, so the caller passes it (1023 = off)."""
    rig = cfg.rig
    lim = rig.limits
    if not 0 <= encoder_counts_per_rev <= 0xFFFF:
        raise ValueError(f"encoder_counts_per_rev {encoder_counts_per_rev} does not fit CONFIGURE's 16 bits")
    enc_min, enc_max = angle_limits_counts(lim.min_angle_deg, lim.max_angle_deg, encoder_counts_per_rev,
                                           encoder_direction)
    return Configure(
        sample_rate_hz=round(rig.sample_rate_hz),
        watchdog_ms=int(rig.watchdog_ms),
        max_duty=duty_units(lim.max_duty),
        max_heating_ms=round(lim.max_heating_s * 1000.0),
        force_limit_counts=int(force_limit_counts),
        enc_min=enc_min,
        enc_max=enc_max,
        flags=Configure.FLAG_ESTOP_INPUT if estop_input else 0,
        encoder_counts_per_rev=encoder_counts_per_rev,
    )


def _cpr_hint(info: Hello | None, config: Configure) -> str:
    """Why a CONFIGURE may have been refused: a firmware build pinned to another encoder."""
    cpr, dev = config.encoder_counts_per_rev, info.encoder_counts_per_rev if info else 0
    if cpr and dev and cpr != dev:
        return f"; the device reports {dev} encoder counts/rev, the config {cpr} (a build pinned to another encoder?)"
    return ""


class HardwareInterface(ABC):
    """A rig the host drives: one device with PWM channels, an encoder and ADC inputs.

    Subclasses call ``super().__init__()``, guard each call with ``_require_connected`` /
    ``_require_active`` and move ``state`` on connect and close. The requests (CONFIGURE, ESTOP,
    CLEAR, SET_ENCODER) are written here once, over one back-end hook, ``_request``: how a frame
    reaches the device and how its ACK comes back is all that differs between transports."""

    info: Hello | None  # the device's HELLO (capabilities), once connected
    stats: LinkStats
    state: LifecycleState
    last_sample_time: float  # ``read_sample`` only: the arrival time of the sample it returned last
    last_sample_gap: int  # ``read_sample`` only: that sample's gap (``Arrival.gap``)
    last_reboot: str  # how the last device restart counted in ``stats.reboots`` showed itself

    def __init__(self) -> None:
        self.info = None
        self.stats = LinkStats()
        self.state = LifecycleState.UNCONFIGURED
        self.last_sample_time = 0.0
        self.last_sample_gap = 0
        self.last_reboot = ""
        # a simulated device this host spawned (devices/spawn.py): its process's stalls are told
        # apart from the link's (loop/trip_cause.py); None for a real board or an in-process device
        self.device_process: Any = None
        self._samples: deque[Arrival] = deque()  # received and not yet read, oldest first
        self.faults_reported: deque[FaultReport] = deque(maxlen=256)  # FAULT frames, oldest first
        self._acks: dict[tuple[int, int], int] = {}  # (acked_type, acked_seq) -> result
        self._last_index: int | None = None  # sample_index of the last SAMPLE (gap accounting)
        self._configured: Configure | None = None  # the last CONFIGURE acknowledged (deactivate keeps its limits)

    def _received_sample(self, now: float, msg: Sample) -> None:
        """Book one SAMPLE: counted, queued with the samples missing before it. Gaps and device
        restarts are judged here and only here: a gap in sample_index (mod 2^32) is samples dropped,
        the index going back is a restart (its HELLO was lost) counted in ``stats.reboots``."""
        st = self.stats
        st.samples += 1
        index = msg.sample_index
        last = self._last_index
        gap = 0
        if last is not None:
            gap = (index - last - 1) & 0xFFFFFFFF
            if gap >= 0x80000000:  # the index went back: the device restarted
                self._rebooted(f"sample_index {last} -> {index}")
                gap = 0
            else:
                st.dropped_samples += gap
        self._last_index = index
        self._samples.append(_new_arrival(Arrival, (now, msg, gap)))

    def _rebooted(self, how: str) -> None:
        """Count a device restart (an unsolicited HELLO, or sample_index going back); the stream starts over."""
        self.stats.reboots += 1
        self.last_reboot = how
        self._last_index = None

    def _received_reply(self, msg: object) -> bool:
        """Book an ACK or a FAULT report; False for any other message."""
        if isinstance(msg, Ack):
            self._acks[(msg.acked_type, msg.acked_seq)] = msg.result
        elif isinstance(msg, FaultReport):
            self.faults_reported.append(msg)
        else:
            return False
        return True

    @abstractmethod
    def connect(self, timeout: float = 2.0) -> Hello:
        """Open the link and handshake; returns the device's capabilities. UNCONFIGURED -> INACTIVE
        (a connected interface re-handshakes and keeps its state)."""

    def configure(self, config: Configure, timeout: float = 1.0) -> None:
        """Send rate, watchdog and limits; raises ``HardwareError`` if the device refuses (the state
        is then unchanged). INACTIVE or ACTIVE -> ACTIVE."""
        self._require_connected("configure")
        self._configure(config, timeout)
        self.state = LifecycleState.ACTIVE

    def deactivate(self, config: Configure | None = None, timeout: float = 1.0) -> None:
        """ros2_control's on_deactivate: PWM off and streaming stopped, the link and the device's
        safety limits kept; ``configure()`` activates again. ACTIVE or INACTIVE -> INACTIVE (a device
        still streaming for an earlier connection stops too).

        The device's one way to stop streaming is a CONFIGURE at rate 0; it goes with max duty 0,
        so no COMMAND can drive until the next ``configure()``, and the other fields (watchdog,
        heating time, force and range limits) of ``config``, else of the last CONFIGURE acknowledged.
        Raises ``HardwareError`` if there is neither, or the device refuses."""
        self._require_connected("deactivate")
        limits = config if config is not None else self._configured
        if limits is None:
            raise HardwareError("deactivate: no CONFIGURE acknowledged yet to take the limits from; pass one")
        self._configure(dataclasses.replace(limits, sample_rate_hz=0, max_duty=0), timeout)
        self.state = LifecycleState.INACTIVE

    @abstractmethod
    def read(self, timeout: float | None = None) -> Arrival | None:
        """The next SAMPLE in arrival order with its arrival time and gap, or None after ``timeout``
        seconds (None: wait forever; 0: take what the link holds now). Connected states only.

        The loop's hot path, once per sample: implementations return the queued ``Arrival`` itself
        and write no attribute."""

    def read_sample(self, timeout: float | None = None) -> Sample | None:
        """``read`` for callers that want the sample alone (homing, doctor, tests): sets
        ``last_sample_time`` and ``last_sample_gap`` from its ``Arrival``."""
        if not self.state.connected:
            self._require_connected("read_sample")
        arrival = self.read(timeout)
        if arrival is None:
            return None
        self.last_sample_time, sample, self.last_sample_gap = arrival
        return sample

    def pending_samples(self) -> int:
        """Samples received and not yet returned by ``read`` (without touching the link)."""
        return len(self._samples)

    def discard_pending(self) -> int:
        """Drop samples received and not yet read (those of the stream before a CONFIGURE or CLEAR
        was acknowledged); returns how many."""
        n = len(self._samples)
        self._samples.clear()
        return n

    @abstractmethod
    def write_command(self, duty0: float, duty1: float = 0.0, direction: int = 0, enable: bool = True) -> int:
        """Send duties (0..1 per channel) and direction bits now (ACTIVE only); returns the COMMAND's seq."""

    def set_encoder(self, count: int = 0, timeout: float = 1.0) -> None:
        """Set the device's encoder count (SET_ENCODER; homing: the home pose's count), connected
        states; waits for the ACK."""
        self._require_connected("set_encoder")
        result = self._request(SetEncoder(int(count)), timeout)
        if result != 0:
            raise HardwareError(f"SET_ENCODER {count} answered with result {result}")

    def estop(self, timeout: float = 1.0) -> None:
        """Emergency stop: PWM off on the device, ESTOP_COMMAND latched; waits for the ACK."""
        self._require_connected("estop")
        result = self._request(EStop(), timeout)
        if result != 0:
            raise HardwareError(f"ESTOP answered with result {result}")

    def clear(self, timeout: float = 1.0) -> bool:
        """Clear latched faults whose cause is gone; True if none remain."""
        self._require_connected("clear")
        return self._request(Clear(), timeout) == 0

    @abstractmethod
    def close(self) -> None:
        """Stop streaming if possible and release the link; idempotent. Any state -> FINALIZED."""

    # ---- requests: the back-end hook ----------------------------------------------------------

    @abstractmethod
    def _request(self, msg: Message, timeout: float) -> int:
        """Send one request and return its ACK's result; raise ``HardwareError`` if none comes
        within ``timeout`` (a back-end may resend a lost request, and must not return while a copy
        could still reach the device)."""

    def _configure(self, config: Configure, timeout: float) -> None:
        """Send ``config`` and check its ACK; the stream restarts, so gap accounting does too."""
        result = self._request(config, timeout)
        if result != 0:
            raise HardwareError(f"device refused CONFIGURE {config} (ACK result {result})"
                                + _cpr_hint(self.info, config))
        self._last_index = None  # the stream restarts: no gap accounting across it
        self._configured = config

    # ---- lifecycle guards ---------------------------------------------------------------------

    def _require_connected(self, action: str) -> None:
        """Raise ``HardwareError`` unless INACTIVE or ACTIVE."""
        if not self.state.connected:
            raise HardwareError(f"{action}: the hardware is {self.state.value}; {_NEXT_STEP[self.state]}")

    def _require_active(self, action: str) -> None:
        """Raise ``HardwareError`` unless ACTIVE (configured)."""
        if self.state is not LifecycleState.ACTIVE:
            raise HardwareError(f"{action}: the hardware is {self.state.value}; {_NEXT_STEP[self.state]}")

    def __enter__(self) -> HardwareInterface:
        return self

    def __exit__(self, exc_type: type[BaseException] | None, exc: BaseException | None,
                 tb: TracebackType | None) -> None:
        self.close()
