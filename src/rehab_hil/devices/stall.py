"""A simulated device's own stalls: wall time in which its process was not scheduled.

A microcontroller is never descheduled; a simulated one on a busy machine is. The device measures
the time between two of its wakes that it did not spend in the sleep it asked for (the Python
device), or simulated time falling behind the wall clock at once (the avr driver)
(``StallMeter.observe``); ``STALL_MIN_S`` or more is a stall of the device, not something the host did. The Python
device then does not count those ticks towards its watchdog (``DeviceCore.tick(watch_host=False)``)
when the host's commands arrived meanwhile, and every device reports its stalls on stderr and in
its ``status`` line (``not_scheduled=N not_scheduled_total_ms=.. not_scheduled_max_ms=..``).
"""

from __future__ import annotations

import sys
from dataclasses import dataclass
from typing import TextIO

__all__ = ["STALL_MIN_S", "StallMeter", "parse_status"]

# 5 ms: five base ticks. A device that is merely busy falls behind by a tick or two per wake (a
# plant step costs 20-60 us, a wake ~0.1 ms); only a descheduled process jumps this far at once,
# and it is a tenth of the shortest watchdog shipped (configs/*.toml: watchdog_ms 50).
STALL_MIN_S = 0.005


@dataclass
class StallMeter:
    """Counts the stalls of one device process and logs each one."""

    min_s: float = STALL_MIN_S
    count: int = 0
    total_s: float = 0.0
    longest_s: float = 0.0
    name: str = "sim device"
    log: TextIO | None = None

    def observe(self, grown_s: float, device_time_s: float, note: str = "") -> bool:
        """``grown_s``: the time the device lost since its last look (see the module docstring).
        Returns True (and counts and logs it) when that is a stall."""
        if grown_s < self.min_s:
            return False
        self.count += 1
        self.total_s += grown_s
        self.longest_s = max(self.longest_s, grown_s)
        print(f"{self.name}: not scheduled for {grown_s * 1e3:.1f} ms at device time {device_time_s:.3f} s"
              f"{'; ' + note if note else ''}", file=self.log or sys.stderr, flush=True)
        return True

    def status(self) -> str:
        """The ``status`` line's fields."""
        return (f"not_scheduled={self.count} not_scheduled_total_ms={self.total_s * 1e3:.1f} "
                f"not_scheduled_max_ms={self.longest_s * 1e3:.1f}")


def parse_status(line: str) -> dict[str, float]:
    """The stall fields of a device's ``status`` reply (absent fields: not reported)."""
    out: dict[str, float] = {}
    for part in line.split():
        key, _, value = part.partition("=")
        if key.startswith("not_scheduled"):
            try:
                out[key] = float(value)
            except ValueError:
                continue
    return out
