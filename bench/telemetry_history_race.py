"""Why the subscribers' history goes alone (``telemetry/subscriber.py``, ``HISTORY_BATCHES``): late
joiners of a busy publisher, counted with zenoh's AdvancedSubscriber configured as this project does
(history of every cached batch) and with recovery (heartbeat) or late-publisher detection added. A
join fails when its first sample is not the publisher's first (zenoh dropped the history it fetched).
Prints the count per configuration.

Usage: python bench/telemetry_history_race.py [--joins 10] [--put-every 0.0002]
"""

from __future__ import annotations

import argparse
import struct
import threading
import time

import zenoh
from zenoh import ext

from rehab_hil.telemetry.session import NetworkConfig, build_zenoh_config
from rehab_hil.telemetry.subscriber import HISTORY_BATCHES
from rehab_hil.testing import free_port

CONFIGS = {
    "history alone (shipped)": {},
    "history + recovery (heartbeat)": {"recovery": True},
    "history + late-publisher detection": {"detect": True},
}


def joins(port: int, n: int, recovery: bool = False, detect: bool = False) -> int:
    """How many of ``n`` late joins did not start at the publisher's first put."""
    failed = 0
    for _ in range(n):
        session = zenoh.open(build_zenoh_config(NetworkConfig(port=port)))
        got: list[int] = []
        sub = ext.declare_advanced_subscriber(
            session, "bench/x", lambda s, got=got: got.append(struct.unpack_from("<I", s.payload.to_bytes())[0]),
            history=ext.HistoryConfig(detect_late_publishers=detect, max_samples=HISTORY_BATCHES),
            recovery=ext.RecoveryConfig(periodic_queries=None, heartbeat=True) if recovery else None)
        time.sleep(1.0)
        failed += not got or got[0] != 0
        sub.undeclare()
        session.close()
    return failed


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--joins", type=int, default=10)
    ap.add_argument("--put-every", type=float, default=0.0002, help="seconds between the publisher's puts")
    args = ap.parse_args()
    zenoh.init_log_from_env_or("error")
    port = free_port()
    hub = zenoh.open(build_zenoh_config(NetworkConfig(role="hub", port=port)))
    block = zenoh.CongestionControl.BLOCK
    pub = ext.declare_advanced_publisher(
        hub, "bench/x", congestion_control=block, cache=ext.CacheConfig(100_000),
        sample_miss_detection=ext.MissDetectionConfig(heartbeat=None, sporadic_heartbeat=0.1), publisher_detection=True)
    stop = threading.Event()

    def put() -> None:
        i = 0
        while not stop.is_set():
            pub.put(struct.pack("<I", i) + bytes(1252))  # a state batch's size
            i += 1
            time.sleep(args.put_every)

    th = threading.Thread(target=put)
    th.start()
    time.sleep(1.0)
    try:
        for name, kw in CONFIGS.items():
            print(f"{name:36s}: {joins(port, args.joins, **kw)} of {args.joins} late joins lost the history",
                  flush=True)
    finally:
        stop.set()
        th.join()
        pub.undeclare()
        hub.close()


if __name__ == "__main__":
    main()
