"""Clients that are not this project's code: Foxglove's own npm client (@foxglove/ws-protocol,
installed by scripts/install_node_clients.sh), a classic-subprotocol WebSocket client, and the
``mcap`` package's reader with CRC validation. Each receives what the local recording holds."""

from __future__ import annotations

import json
import shutil
import subprocess
import sys
import threading
from pathlib import Path

import pytest
from mcap.reader import make_reader

from rehab_hil.loading import load_config
from rehab_hil.loop.recorder import Recorder, read_mcap
from rehab_hil.plants import get_plant
from rehab_hil.service.session import open_session
from rehab_hil.telemetry.foxglove import FoxgloveLive, topics
from rehab_hil.telemetry.ws_subprotocol import CLASSIC, SDK, rewrite_request, rewrite_response

from .fake_rig import LockstepRig, RampController
from .fgclient import FoxgloveClient

ROOT = Path(__file__).resolve().parents[2]
CONFIG = ROOT / "configs" / "finger_extensor.toml"
CLIENTS = ROOT / "tests" / "clients"


def _session(feed, tmp_path: Path) -> list[tuple[str, dict]]:
    """A 0.3 s lockstep session fed to ``feed`` and recorded; the recording's (topic, message)."""
    local = Recorder(tmp_path, _binding())
    try:
        with open_session(CONFIG, hw=LockstepRig(), controller=RampController(),
                          sinks=(local,) if feed is None else (local, feed), realtime=False,
                          sample_timeout_s=0.5) as session:
            result = session.run(0.3)
    finally:
        local.close()
    assert result.cycles > 200 and not result.events
    return [(topic, msg) for topic, _, msg in read_mcap(tmp_path / "run.mcap")]


def _binding():  # type: ignore[no-untyped-def]
    cfg = load_config(CONFIG)
    return get_plant(cfg.plant).device(cfg)


def test_the_handshake_rewrite_maps_only_a_classic_only_offer():
    req = b"GET / HTTP/1.1\r\nHost: x\r\nSec-WebSocket-Protocol: foxglove.websocket.v1\r\n\r\n"
    out, back = rewrite_request(req)
    assert back == CLASSIC and b"Sec-WebSocket-Protocol: foxglove.sdk.v1\r\n" in out
    both = req.replace(b"foxglove.websocket.v1", b"foxglove.websocket.v1, foxglove.sdk.v1")
    assert rewrite_request(both) == (both, None)  # the SDK's own name is there: untouched
    other = req.replace(b"foxglove.websocket.v1", b"chat")
    assert rewrite_request(other) == (other, None)  # the SDK server refuses it itself
    answer = b"HTTP/1.1 101 Switching Protocols\r\nsec-websocket-protocol: foxglove.sdk.v1\r\n\r\n"
    assert rewrite_response(answer, CLASSIC) == answer.replace(b"foxglove.sdk.v1", b"foxglove.websocket.v1")


@pytest.mark.parametrize("subprotocol", [SDK, CLASSIC])
def test_both_subprotocols_receive_the_channels_and_the_recorded_samples(subprotocol, tmp_path, wait):
    t = topics("/rig")
    with FoxgloveLive(port=0) as live:
        feed = live.add_rig(_binding())
        client = FoxgloveClient(live.port, [t["sample"], t["command"]], subprotocol=subprotocol)
        try:
            assert client.wait_subscribed(), client.error
            assert wait(lambda: feed.channels["sample"].has_sinks() and feed.channels["command"].has_sinks())
            recorded = _session(feed, tmp_path)
            want = [m for topic, m in recorded if topic == t["sample"]]
            assert wait(lambda: len(client.messages[t["sample"]]) == len(want))
        finally:
            client.close()
    assert client.error is None and client.negotiated == subprotocol
    assert set(client.channels) == set(t.values())
    assert client.messages[t["sample"]] == want
    assert client.messages[t["command"]] == [m for topic, m in recorded if topic == t["command"]]


@pytest.fixture(scope="module")
def node_client():
    if shutil.which("node") is None:
        pytest.skip("no node on PATH: the npm client test needs Node.js")
    proc = subprocess.run(["sh", str(ROOT / "scripts" / "install_node_clients.sh")], capture_output=True, text=True,
                          timeout=600)
    if proc.returncode != 0:
        pytest.skip(f"scripts/install_node_clients.sh failed (npm registry unreachable?): {proc.stderr.strip()[-300:]}")
    return CLIENTS / "foxglove_client.mjs"


def test_the_sdk_server_alone_refuses_the_classic_subprotocol_the_front_accepts():
    from websockets.exceptions import InvalidStatus
    from websockets.sync.client import connect

    with FoxgloveLive(port=0) as live:
        with pytest.raises(InvalidStatus, match="400"), connect(f"ws://127.0.0.1:{live.server.port}",
                                                                subprotocols=[CLASSIC]):
            pass
        with connect(f"ws://127.0.0.1:{live.port}", subprotocols=[CLASSIC]) as ws:
            assert ws.subprotocol == CLASSIC and json.loads(ws.recv(timeout=10))["op"] == "serverInfo"


@pytest.mark.parametrize("subprotocol", [CLASSIC, SDK])
def test_foxgloves_npm_client_receives_the_channels_and_the_recorded_samples(node_client, subprotocol, tmp_path,
                                                                             wait):
    t = topics("/rig")
    lines: list[dict] = []
    with FoxgloveLive(port=0) as live:
        feed = live.add_rig(_binding())
        node = subprocess.Popen(["node", str(node_client), f"ws://127.0.0.1:{live.port}",
                                 f"{t['sample']},{t['command']}", subprotocol], cwd=CLIENTS, stdin=subprocess.PIPE,
                                stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        reader = threading.Thread(target=lambda: lines.extend(json.loads(x) for x in node.stdout), daemon=True)
        reader.start()
        try:
            assert wait(lambda: feed.channels["sample"].has_sinks() and feed.channels["command"].has_sinks()), \
                node.stderr.read() if node.poll() is not None else "no subscription"
            recorded = _session(feed, tmp_path)
            want = [m for topic, m in recorded if topic == t["sample"]]

            def got(topic: str) -> list[dict]:
                return [x["data"] for x in list(lines) if x["op"] == "message" and x["topic"] == topic]

            assert wait(lambda: len(got(t["sample"])) == len(want))
        finally:
            node.stdin.close()
            try:
                node.wait(timeout=30)
            except subprocess.TimeoutExpired:
                node.kill()
                node.wait()
            reader.join(10)
    assert node.returncode == 0, node.stderr.read()
    assert [x["protocol"] for x in lines if x["op"] == "protocol"] == [subprotocol]
    advertised = {ch["topic"]: ch for x in lines if x["op"] == "advertise" for ch in x["channels"]}
    assert set(advertised) == set(t.values())
    assert all(ch["encoding"] == "json" and ch["schemaEncoding"] == "jsonschema" for ch in advertised.values())
    assert got(t["sample"]) == want  # every field, value for value
    assert got(t["command"]) == [m for topic, m in recorded if topic == t["command"]]


def test_a_recording_reads_back_with_the_mcap_reader_validating_crcs(tmp_path):
    recorded = _session(None, tmp_path)
    with open(tmp_path / "run.mcap", "rb") as fh:
        reader = make_reader(fh, validate_crcs=True)
        summary = reader.get_summary()
        read = [(ch.topic, json.loads(msg.data)) for _, ch, msg in reader.iter_messages(log_time_order=False)]
    assert summary is not None and summary.statistics.message_count == len(recorded)
    assert read == recorded
    assert {ch.topic for ch in summary.channels.values()} >= {"/rig/sample", "/rig/command"}
    assert sum(1 for t, _ in read if t == "/rig/sample") > 200


def _docs_block(heading: str) -> str:
    text = (ROOT / "docs" / "telemetry.md").read_text()
    section = text[text.index(heading):]
    start = section.index("```python\n") + len("```python\n")
    return section[start:section.index("\n```", start)]


def test_a_plain_zenoh_subscriber_written_from_the_docs_alone_decodes_the_published_samples(client, hub,
                                                                                             tmp_path, wait):
    import math

    from rehab_hil.loop.controllers import Command
    from rehab_hil.loop.estimation import State
    from rehab_hil.loop.records import CommandRecord, SampleRecord
    from rehab_hil.protocol import Sample
    from rehab_hil.telemetry import TelemetryPublisher

    code = _docs_block("### Without this project's code")
    assert "rehab_hil" not in code  # the docs' code, nothing of ours
    script = tmp_path / "plain_subscriber.py"
    script.write_text(code)
    n = 40
    records = []
    for i in range(n):  # a sample record (with two analog signals), then the command record of that cycle
        s = Sample(1000 * i, i, 3 * i, 100 + i, 200 + i, 2500, 0, 1, 4, 0, i, 2)
        st = State(i * 1e-3, math.radians(0.5 * i), 0.1, {"force_n": 1.5 * i, "torque_nm": -0.25 * i})
        cmd = Command((0.25 + i / 1000, 0.0), reference_deg=10.0 + i)
        records += [SampleRecord(0.0, i * 1e-3, s, st, cmd, i, 30.0 + i), CommandRecord(0.0, i * 1e-3, cmd, i, 30.0)]
    proc = subprocess.Popen([sys.executable, str(script), "plain1", f"tcp/127.0.0.1:{hub}", str(n)],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        assert proc.stdout.readline().strip() == "subscribed", proc.stderr.read()
        with TelemetryPublisher(client(), "plain1", batch=10) as pub:
            # "subscribed" is said when the subscriber is declared in its own session; the router and
            # this session learn of it a moment later (beside two busy loops the first batch of 10 went
            # out before: the subscriber got samples 10..39)
            assert wait(pub.has_subscribers), "the subscriber never reached the publisher"
            for r in records:
                assert pub.offer(r)
            pub.wake()
        out, err = proc.communicate(timeout=90)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.communicate()
    assert proc.returncode == 0, err
    got = [json.loads(line) for line in out.splitlines()]
    assert [g["sample_index"] for g in got] == list(range(n))
    for i, g in enumerate(got):
        assert g["angle_deg"] == pytest.approx(0.5 * i) and g["analog"] == [1.5 * i, -0.25 * i]
        assert (g["encoder_count"], g["adc0"], g["adc1"], g["rx_bad_frames"]) == (3 * i, 100 + i, 200 + i, 2)
        assert g["reference_deg"] == 10.0 + i and g["command_duty0"] == 0.25 + i / 1000
        assert g["temperature_c"] == 30.0 + i and g["time_s"] == i * 1e-3
