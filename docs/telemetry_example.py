"""Custom subscriber example (docs/telemetry.md): print the first N samples of a rig, then exit.

    python docs/telemetry_example.py RIG [--port 7447] [--count 10] [--wait 60]

Start it before or after the rig: started first, it waits (up to --wait s) for the rig's hub; started
late, it still gets the rig's first samples (the publisher's history). tests/telemetry/
test_docs_example.py runs this file both ways against a live publisher.
"""

from __future__ import annotations

import argparse
import threading

from rehab_hil.telemetry import NetworkConfig, StateSample, subscribe


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("rig")
    ap.add_argument("--port", type=int, default=7447)
    ap.add_argument("--count", type=int, default=10)
    ap.add_argument("--timeout", type=float, default=30.0, help="for the samples, once subscribed [s]")
    ap.add_argument("--wait", type=float, default=60.0, help="for the hub, if the rig is not running yet [s]")
    args = ap.parse_args()

    got: list[StateSample] = []
    done = threading.Event()

    def on_sample(s: StateSample) -> None:  # runs on a zenoh thread: keep it short
        if len(got) < args.count:
            got.append(s)
        if len(got) == args.count:
            done.set()

    # a client session to the loopback hub on --port (waiting for it up to --wait s); closed when the
    # block ends. The first samples come from the rig publisher's history, then live ones, in order.
    with subscribe(args.rig, on_sample, net=NetworkConfig(port=args.port), wait_s=args.wait) as sub:
        done.wait(args.timeout)
    for s in got:
        print(f"sample {s.sample_index}: angle {s.angle_deg:.2f} deg, duty {s.command_duty0:.3f}, "
              f"temperature {s.temperature_c:.1f} C")
    print(f"received {len(got)} samples, {sub.missing_batches} batches missing")


if __name__ == "__main__":
    main()
