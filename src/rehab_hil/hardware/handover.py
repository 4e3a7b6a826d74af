"""``LinkHandover``: how a ``SerialHardware`` crosses to a loop process (``loop.process``) and back.

The link is two things: its state (counters, sequence numbers, the lifecycle state, queued samples, a
partly decoded frame), which pickles, and its OS handles (the ``SerialPort``, the write lock), which
stay in each process. The state goes over as a dict (``link_state``), the port as its file descriptor
passed to the process as it is started (``handed_over``); after the run the session's copy takes the
state back (``adopt_link_state``). Kept apart from ``SerialHardware``, which talks to the device.
"""

from __future__ import annotations

import threading
from typing import Any, Self

from rehab_hil.hardware.interface import LifecycleState, LinkStats
from rehab_hil.hardware.serial_port import SerialPort
from rehab_hil.protocol import FrameDecoder

__all__ = ["LinkHandover"]

_OS_HANDLES = ("_port", "_wlock")  # what stays in each process


class LinkHandover:
    """The crossing, mixed into ``SerialHardware``: its port (``_port``, None when closed), write lock
    (``_wlock``) and decoder (``_decoder``, whose counter ``stats.bad_frames`` is) are what it handles."""

    port: str
    write_timeout_s: float
    state: LifecycleState
    stats: LinkStats
    _port: SerialPort | None
    _wlock: threading.Lock
    _decoder: FrameDecoder

    @classmethod
    def handed_over(cls, state: dict[str, Any], fd: int) -> Self:
        """The link a session's process handed to a loop process (``loop.process``): its state
        (``link_state``) and the port's file descriptor, passed to the process as it was started, so the
        port is neither opened again (an Arduino's reset) nor closed; the session's copy stays open beside
        it, idle while the loop process runs."""
        hw = cls.__new__(cls)
        hw.__dict__.update(state)
        hw._port = SerialPort.handed_over(hw.port, fd, hw.write_timeout_s)
        hw._wlock = threading.Lock()
        hw.stats.bad_frames = hw._decoder.bad
        return hw

    @property
    def fd(self) -> int:
        """The open port's file descriptor (-1 when closed)."""
        return -1 if self._port is None else self._port.fd

    def link_state(self) -> dict[str, Any]:
        """What the link knows besides its OS handles: counters, sequence numbers, the lifecycle state,
        queued samples and a partly decoded frame (``adopt_link_state`` takes it back after a run)."""
        skip = (*_OS_HANDLES, "device_process")
        return {k: v for k, v in self.__dict__.items() if k not in skip}

    def close_handed(self) -> None:
        """A loop process's end: release its copy of the handed-over port, sending nothing (the session's
        copy goes on)."""
        port, self._port = self._port, None
        if port is not None:
            port.ser.close()
        self.state = LifecycleState.FINALIZED

    def adopt_link_state(self, state: dict[str, Any]) -> None:
        """Go on where a loop process's copy of this link stopped (its bytes were read there)."""
        self.__dict__.update({k: v for k, v in state.items() if k not in _OS_HANDLES})
        self.stats.bad_frames = self._decoder.bad
