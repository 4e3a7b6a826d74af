"""``rehab-hil foxglove [RIG ...]``: bridge rigs' zenoh telemetry to a Foxglove WebSocket server, on any
machine of the lab, so the loop process serves nothing extra (docs/telemetry.md, "Live view in Foxglove").

One named rig gets the ``/rig/...`` topics of docs/foxglove_layout.json; several (or none named: every
live rig, and rigs that appear later) get ``/rigs/<rig>/...``; ``--layout-out`` writes their layout.
"""

from __future__ import annotations

import argparse
import math
import time
from pathlib import Path
from typing import Any

from rehab_hil import shipped
from rehab_hil.cli import UserError, config_file
from rehab_hil.telemetry.cliargs import add_network_args, network_from_args
from rehab_hil.telemetry.codec import PayloadError, decode_json
from rehab_hil.telemetry.foxglove import DEFAULT_HOST, DEFAULT_PORT, FoxgloveError, FoxgloveLive, RigFeed, rig_prefix
from rehab_hil.telemetry.foxglove_layout import layout_json
from rehab_hil.telemetry.keys import RigIdError, RigKeys, validate_rig_id
from rehab_hil.telemetry.lab import LabError, RigWatch, binding_from_info
from rehab_hil.telemetry.session import TelemetryConfigError, open_session
from rehab_hil.telemetry.subscriber import Subscription, list_rigs, query_info, subscribe
from rehab_hil.telemetry.zrecord import to_record
from rehab_hil.twin.outputs import SinkOutput, prediction_topic


def add_parser(sub: argparse._SubParsersAction) -> argparse.ArgumentParser:
    p = sub.add_parser("foxglove", help="serve rigs' zenoh telemetry to Foxglove over its WebSocket protocol")
    p.add_argument("rigs", nargs="*", metavar="RIG", help="rig ids (default: every live rig)")
    p.add_argument("--ws-port", type=int, default=DEFAULT_PORT, help=f"Foxglove server port (default {DEFAULT_PORT})")
    p.add_argument("--ws-host", default=DEFAULT_HOST, help=f"address the server binds (default {DEFAULT_HOST})")
    p.add_argument("--layout-out", type=Path, default=None, help="write a Foxglove layout for the bridged rigs")
    p.add_argument("--config", type=config_file, default=None, help="plant config (default: what each rig reports)")
    p.add_argument("--duration", type=float, default=None, help="stop after this many seconds (default: Ctrl-C)")
    p.add_argument("--wait", type=float, default=10.0, help="how long to wait for the rigs to appear [s] (default 10)")
    add_network_args(p)
    return p


class Bridge:
    """Rigs' zenoh subscriptions feeding one ``FoxgloveLive`` (records converted back to loop records)."""

    def __init__(self, session: Any, live: FoxgloveLive, several: bool, config: Path | None) -> None:
        self.session, self.live, self.several, self.config = session, live, several, config
        self.feeds: dict[str, RigFeed] = {}
        self.subs: dict[str, Subscription] = {}
        self.twins: dict[str, Any] = {}
        self.bad = 0

    def add(self, rig: str) -> str:
        info = query_info(self.session, rig, timeout_s=2.0)
        if info is None and self.config is None:
            raise LabError(f"rig {rig!r} did not answer on rehab/{rig}/info")
        binding = binding_from_info(info, rig, self.config)
        names = (info or {}).get("analog_names") or [ch.signal for ch in binding.adc]
        feed = self.live.add_rig(binding, rig_prefix(rig, self.several))

        def on_sample(s: Any) -> None:
            try:
                feed.offer(to_record(s, names))
            except ValueError:
                self.bad += 1

        def on_safety(m: dict[str, Any]) -> None:
            t = m.get("t_s")
            feed.event(float(t) if isinstance(t, (int, float)) else math.nan, str(m.get("reason", m.get("state"))),
                       str(m.get("detail", "")))

        self.subs[rig] = subscribe(rig, on_sample, on_stats=feed.stats, on_safety=on_safety, session=self.session)
        self.twins[rig] = self._twin(rig, feed)
        self.feeds[rig] = feed
        return f"rig {rig} -> {feed.prefix}/{{sample,command,event,stats}}, {prediction_topic(feed.prefix)}"

    def _twin(self, rig: str, feed: RigFeed) -> Any:
        """The rig's live twin (``rehab/<rig>/twin``, when it runs one) onto its prediction topic and events."""
        out = SinkOutput(feed)

        def on_twin(s: Any) -> None:
            try:
                m = decode_json(s.payload.to_bytes())
            except PayloadError:
                self.bad += 1
                return
            if m["kind"] == "prediction":
                out.prediction({k: v for k, v in m.items() if isinstance(v, float | int) and k != "v"})
            elif m["kind"] == "model_mismatch" and m.get("final"):
                feed.event(float(m.get("t_s", math.nan)), "model_mismatch", str(m.get("text", "")))

        return self.session.declare_subscriber(RigKeys(rig).twin, on_twin)

    def close(self) -> None:
        for s in self.subs.values():
            s.close()
        for t in self.twins.values():
            t.undeclare()


def run(args: argparse.Namespace) -> int:
    try:
        wanted = [validate_rig_id(r) for r in args.rigs]
        net = network_from_args(args)
    except (RigIdError, TelemetryConfigError) as e:
        raise UserError(str(e)) from None
    if args.duration is not None and not 0 < args.duration <= 7 * 24 * 3600:
        raise UserError(f"--duration must be positive (and at most a week), got {args.duration}")
    try:
        session = open_session(net)
    except TelemetryConfigError as e:
        raise UserError(str(e)) from None
    try:
        try:
            live = FoxgloveLive(args.ws_host, args.ws_port, name="rehab-hil lab")
        except FoxgloveError as e:
            raise UserError(str(e)) from None
        watch = RigWatch(session, (lambda r: r in wanted) if wanted else (lambda r: True))
        bridge = Bridge(session, live, several=len(wanted) != 1, config=args.config)
        try:
            end_wait = time.monotonic() + args.wait
            while True:  # the named rigs (or at least one rig) before serving
                present = set(list_rigs(session, timeout_s=0.5))
                missing = [r for r in wanted if r not in present]
                if (wanted and not missing) or (not wanted and present):
                    break
                if time.monotonic() >= end_wait:
                    what = f"rig(s) {', '.join(missing)} not live" if wanted else "no live rig"
                    raise UserError(f"{what} within {args.wait} s (live: {', '.join(sorted(present)) or 'none'})")
                time.sleep(0.2)
            for rig in sorted(present if not wanted else wanted):
                try:
                    print(bridge.add(rig), flush=True)
                except (LabError, ValueError) as e:
                    raise UserError(str(e)) from None
            if args.layout_out is not None:
                args.layout_out.write_text(layout_json([(bridge.feeds[r].prefix, r) for r in sorted(bridge.feeds)]))
            print(f"Foxglove: open {live.url} (layout: {args.layout_out or shipped.FOXGLOVE_LAYOUT})", flush=True)
            end = time.monotonic() + args.duration if args.duration else float("inf")
            try:
                while time.monotonic() < end:
                    for rig, alive in watch.changes():
                        if alive and rig not in bridge.feeds and not wanted:
                            try:
                                print(bridge.add(rig), flush=True)
                            except (LabError, ValueError) as e:
                                print(f"rig {rig}: not bridged: {e}", flush=True)
                    time.sleep(0.1)
            except KeyboardInterrupt:
                pass
        finally:
            bridge.close()
            watch.close()
            live.close()
        dropped = sum(f.dropped for f in bridge.feeds.values())
        sent = sum(f.sent for f in bridge.feeds.values())
        print(f"bridge stopped: {sent} messages sent to Foxglove clients, {dropped} records dropped (queue full)")
    finally:
        session.close()
    return 0
