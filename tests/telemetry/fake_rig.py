"""An in-process lockstep rig for telemetry tests: every COMMAND produces the next SAMPLE at once.

Deterministic and CPU-cheap (no subprocess, no plant model), so the loop service can run with a
recorder and a zenoh publisher inside a unit test.
"""

from __future__ import annotations

import math
from collections import deque

from rehab_hil.hardware.interface import HardwareInterface, LinkStats, duty_units
from rehab_hil.protocol import Configure, Hello, Sample, Status


class LockstepRig(HardwareInterface):
    def __init__(self) -> None:
        self.info: Hello | None = None
        self.stats = LinkStats()
        self._pending: deque[Sample] = deque()
        self._i = 0
        self._seq = 0
        self._count = 0.0

    def connect(self, timeout: float = 2.0) -> Hello:
        self.info = Hello(1, 1, 2, 3, 2, 2, 2000, 5000, 10, 1000, 0)
        return self.info

    def configure(self, config: Configure, timeout: float = 1.0) -> None:
        pass

    def read_sample(self, timeout: float | None = None) -> Sample | None:
        s = self._pending.popleft() if self._pending else None
        if s is not None:
            self.stats.samples += 1
        return s

    def pending_samples(self) -> int:
        return len(self._pending)

    def write_command(self, duty0: float, duty1: float = 0.0, direction: int = 0, enable: bool = True) -> int:
        self._seq = (self._seq + 1) & 0xFFFF
        d0 = duty_units(duty0) if enable else 0
        self._count += (-1 if direction & 1 else 1) * d0 / 20_000.0
        self._pending.append(Sample(
            device_time_us=self._i * 1000, sample_index=self._i, encoder_count=int(self._count),
            adc0=512 + int(100 * math.sin(self._i / 50)), adc1=0, duty0=d0, duty1=0, direction=direction,
            status=Status.STREAMING | (Status.PWM_ENABLED if d0 else 0), faults=0, cmd_seq_echo=self._seq,
            rx_bad_frames=0))
        self._i += 1
        self.stats.frames_tx += 1
        return self._seq

    def estop(self, timeout: float = 1.0) -> None:
        pass

    def clear(self, timeout: float = 1.0) -> bool:
        return True

    def close(self) -> None:
        pass


class RampController:
    """Duty follows a slow sine towards a 30 deg reference: enough variety for every column."""

    def reset(self) -> None:
        pass

    def __call__(self, t_s: float, state: object) -> object:
        from rehab_hil.service.controllers import Command

        return Command((0.3 + 0.2 * math.sin(8 * t_s), 0.0), 0, True, 30.0 + t_s)
