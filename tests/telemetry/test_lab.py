"""A lab of rigs on loopback: ``rehab-hil router`` (a real process), three in-process rigs as clients,
the monitor's lab table, a multi-rig zenoh recording equal to each rig's local recording, the
router's access control, and the one-line errors."""

from __future__ import annotations

import json
import signal
import subprocess
import sys
import threading
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
import zenoh
from mcap.reader import make_reader

from rehab_hil.cli import main
from rehab_hil.loading import load_config
from rehab_hil.loop.recorder import Recorder
from rehab_hil.loop.run_dir import read_metadata
from rehab_hil.plants import get_plant
from rehab_hil.protocol import Sample
from rehab_hil.service import assembly
from rehab_hil.service.session import open_session as open_rig_session  # beside zenoh's open_session
from rehab_hil.telemetry import (
    NetworkConfig,
    TelemetryConfigError,
    TelemetryPublisher,
    lab,
    list_rigs,
    open_session,
    subscribe,
)
from rehab_hil.telemetry.access import command_access_control
from rehab_hil.telemetry.foxglove import FoxgloveLive
from rehab_hil.telemetry.rig import rig_info
from rehab_hil.testing import free_port

from .fake_rig import LockstepRig, RampController
from .fgclient import FoxgloveClient

CONFIG = Path(__file__).resolve().parents[2] / "configs" / "finger_extensor.toml"


def start_router(*extra: str) -> tuple[subprocess.Popen[str], str]:
    """``rehab-hil router`` in its own process on a free loopback port; returns it and its endpoint."""
    for _ in range(5):
        ep = f"tcp/127.0.0.1:{free_port()}"
        proc = subprocess.Popen([sys.executable, "-m", "rehab_hil.cli", "router", "--listen", ep, "--duration", "120",
                                 *extra], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        assert proc.stdout is not None
        line = proc.stdout.readline()
        if line.startswith("zenoh router listening on"):
            return proc, ep
        _, err = proc.communicate(timeout=10)
    raise RuntimeError(f"no router started: {line!r} {err[-500:]!r}")


def stop_router(proc: subprocess.Popen[str]) -> str:
    """SIGTERM, then its output; a router still running 20 s later is asked where its threads are
    (SIGUSR1: faulthandler), killed, and the test fails showing that."""
    proc.terminate()
    try:
        out, _ = proc.communicate(timeout=20)
    except subprocess.TimeoutExpired:
        proc.send_signal(signal.SIGUSR1)
        time.sleep(1.0)
        proc.kill()
        out, err = proc.communicate(timeout=10)
        raise AssertionError(f"the router did not stop within 20 s of SIGTERM; its stderr:\n{err[-6000:]}") from None
    return out


@pytest.fixture
def router() -> Iterator[str]:
    proc, ep = start_router()
    yield ep
    assert "router stopped after" in stop_router(proc)


def lab_client(ep: str, **kw) -> zenoh.Session:  # type: ignore[no-untyped-def]
    return open_session(NetworkConfig(mode="lab", router=(ep,), **kw))


def test_three_rigs_on_one_router_monitor_and_a_multi_rig_recording(router: str, wait, tmp_path: Path,
                                                                    capsys: pytest.CaptureFixture[str]) -> None:
    cfg = load_config(CONFIG)
    binding = get_plant(cfg.plant).device(cfg)
    rigs = ["lab-a", "lab-b", "lab-c"]
    sessions = {r: lab_client(router) for r in [*rigs, "bench-x"]}
    hws = {r: LockstepRig() for r in rigs}
    info = rig_info(cfg.plant, CONFIG, binding, assembly.period_s(cfg), hws[rigs[0]].info)
    pubs = {r: TelemetryPublisher(sessions[r], r, info=info, queue_size=20_000) for r in sessions}
    try:
        probe = lab_client(router)
        assert wait(lambda: len(list_rigs(probe, timeout_s=0.5)) == 4)  # the tokens reached the router
        probe.close()
        # the monitor without a rig id: one row per live rig
        assert main(["monitor", "--connect", router, "--duration", "1.0", "--no-live"]) == 0
        table = capsys.readouterr().out
        for r in [*rigs, "bench-x"]:
            assert r in table
        assert "4 live rig(s)" in table and table.count("finger_extensor") == 4

        codes: list[int] = []
        rec = threading.Thread(target=lambda: codes.append(main(
            ["record", "--from-zenoh", "lab-*", "--out", str(tmp_path / "zenoh"), "--connect", router])))
        rec.start()
        assert all(wait(pubs[r].has_subscribers, 20) for r in rigs)
        locals_ = {r: Recorder(tmp_path / "local" / r, binding) for r in rigs}
        results = {}

        def session(r: str) -> None:
            with open_rig_session(CONFIG, hw=hws[r], controller=RampController(), sinks=(locals_[r], pubs[r]),
                                  realtime=False, sample_timeout_s=0.5) as rig:
                results[r] = rig.run(0.3)

        loops = [threading.Thread(target=session, args=(r,)) for r in rigs]
        for th in loops:
            th.start()
        for th in loops:
            th.join(60)
        for r in rigs:
            locals_[r].close()
            pubs[r].close()  # the rig stops; the recorder finishes its run directory
        rec.join(60)
    finally:
        for p in pubs.values():
            p.close()
        for s in sessions.values():
            s.close()
    assert codes == [0]
    assert all(results[r].cycles > 200 and not results[r].events for r in rigs)
    dirs = sorted((tmp_path / "zenoh").iterdir(), key=lambda d: d.name.split("-", 1)[1])  # by rig: the runs may
    # start on either side of a second boundary, and the run directory names begin with the UTC second
    assert [d.name.split("-", 1)[1] for d in dirs] == rigs  # one run directory per matching rig, bench-x not
    for d in dirs:
        rig = d.name.split("-", 1)[1]
        assert (d / "run.csv").read_text() == (tmp_path / "local" / rig / "run.csv").read_text()
        meta = read_metadata(d)
        assert meta["rig_id"] == rig and meta["plant"] == "finger_extensor" and meta["records"] > 400
        assert meta["lost"] == {"at_publisher": 0, "before_joining": 0, "in_transit": 0, "in_writer": 0,
                                "unexplained": 0}
        assert meta["samples"]["samples_not_received"] == 0 and meta["samples"]["complete"]  # the rig's count
        with open(d / "run.mcap", "rb") as fh:  # the same metadata as MCAP metadata records
            records = {m.name: m.metadata for m in make_reader(fh).iter_metadata()}
        assert records["rehab_hil.session"]["rig_id"] == rig and records["rehab_hil.summary"]["records"] == str(
            meta["records"])
    assert capsys.readouterr().out.count("rig stopped: rig lab-") == 3


def test_the_router_acl_refuses_an_unauthorised_client_while_telemetry_flows(tmp_path: Path, wait) -> None:
    users = {"rig": "rig-pw", "victor": "view-pw", "mallory": "mal-pw"}
    (tmp_path / "users").write_text("".join(f"{u}:{p}\n" for u, p in users.items()))
    acl = command_access_control(rig_users=["rig"], viewers=["victor"])  # mallory: in no policy
    (tmp_path / "acl.json").write_text(json.dumps({"access_control": acl}))
    proc, ep = start_router("--users", str(tmp_path / "users"), "--access-control", str(tmp_path / "acl.json"))
    try:
        def as_user(u: str) -> zenoh.Session:
            return lab_client(ep, user=u, password=users[u])

        rig, viewer, mallory, mallory_spy = as_user("rig"), as_user("victor"), as_user("mallory"), as_user("mallory")
        with pytest.raises(TelemetryConfigError, match="cannot connect"):
            lab_client(ep)  # no credentials: refused at the handshake
        seen: list[int] = []
        stolen: list[object] = []
        spy = mallory_spy.declare_subscriber("rehab/**", stolen.append)
        try:
            with TelemetryPublisher(rig, "acl1", batch=1) as pub, \
                    subscribe("acl1", lambda s: seen.append(s.sample_index), session=viewer):
                assert wait(pub.has_subscribers)
                fake = mallory.declare_publisher("rehab/acl1/state")
                fake.put(b"RS-forged")  # denied on ingress: the viewer never sees it
                for i in range(20):
                    pub.offer(Sample(i, i, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0))
                assert wait(lambda: len(seen) == 20)
                fake.undeclare()
        finally:
            spy.undeclare()
        assert seen == list(range(20)) and stolen == []
        for s in (rig, viewer, mallory, mallory_spy):
            s.close()
    finally:
        stop_router(proc)


def test_the_foxglove_bridge_serves_a_rig_from_zenoh(router: str, wait, capsys: pytest.CaptureFixture[str]) -> None:
    cfg = load_config(CONFIG)
    binding = get_plant(cfg.plant).device(cfg)
    rig_session = lab_client(router)
    ws_port = free_port()
    hw = LockstepRig()
    pub = TelemetryPublisher(rig_session, "fox1", info=rig_info(cfg.plant, CONFIG, binding, 0.001, hw.info))
    codes: list[int] = []
    bridge = threading.Thread(target=lambda: codes.append(main(
        ["foxglove", "fox1", "--ws-port", str(ws_port), "--connect", router, "--duration", "5"])))
    bridge.start()
    client = None
    try:
        assert wait(pub.has_subscribers)  # the bridge is subscribed, so its server is up
        client = FoxgloveClient(ws_port, ["/rig/sample"])
        assert client.wait_subscribed(), client.error
        with open_rig_session(CONFIG, hw=hw, controller=RampController(), sinks=(pub,), realtime=False,
                              sample_timeout_s=0.5) as session:
            result = session.run(0.2)
        assert wait(lambda: len(client.messages["/rig/sample"]) >= result.samples - 5)
    finally:
        if client is not None:
            client.close()
        pub.close()
        bridge.join(30)
        rig_session.close()
    msgs = client.messages["/rig/sample"]
    idx = [m["sample_index"] for m in msgs]
    assert idx == sorted(idx) and len(set(idx)) == len(idx)
    assert codes == [0] and "rig fox1 -> /rig/{sample,command,event,stats}" in capsys.readouterr().out


def test_bad_lab_input_gets_one_line_errors(router: str, tmp_path: Path, wait,
                                            capsys: pytest.CaptureFixture[str]) -> None:
    nowhere = f"tcp/127.0.0.1:{free_port()}"
    cases = [
        (["monitor", "--connect", nowhere, "--no-live"], "cannot connect to " + nowhere),
        (["record", "--from-zenoh", "lab-*", "--out", str(tmp_path), "--connect", nowhere, "--wait", "0.3"],
         "cannot connect to " + nowhere),
        (["record", "--from-zenoh", "nothing-*", "--out", str(tmp_path), "--connect", router, "--wait", "0.5"],
         "no live rig matches 'nothing-*' within 0.5 s (live rigs: none)"),
        (["record", "--from-zenoh", "a/b", "--out", str(tmp_path), "--connect", router], "rig pattern 'a/b' must"),
        (["foxglove", "ghost", "--connect", router, "--wait", "0.3", "--ws-port", str(free_port())],
         "rig(s) ghost not live within 0.3 s"),
        (["router", "--listen", router], "cannot listen on " + router),
        (["router", "--listen", "udp/nowhere"], "listen endpoint 'udp/nowhere' must look like"),
    ]
    with FoxgloveLive(port=0) as busy:  # a Foxglove port in use: the bridge says so, the server keeps serving
        cases.append((["foxglove", "x", "--connect", router, "--ws-port", str(busy.port)],
                      f"cannot serve Foxglove on 127.0.0.1:{busy.port}: Failed to bind port"))
        for argv, text in cases:
            assert main(argv) == 2, argv
            err = capsys.readouterr().err.strip()
            assert text in err and "\n" not in err, (argv, err)
        viewer = FoxgloveClient(busy.port, [])
        try:
            assert wait(lambda: viewer.server_info.get("op") == "serverInfo")
        finally:
            viewer.close()
    assert list(tmp_path.iterdir()) == []  # nothing written


def test_rehab_hil_run_publishes_as_a_client_of_the_lab_router(router: str, tmp_path: Path,
                                                               capsys: pytest.CaptureFixture[str],
                                                               monkeypatch: pytest.MonkeyPatch) -> None:
    # The rig starts once the recorder watches for rigs: started together, beside two busy loops the
    # recorder's thread had not opened its session and declared its liveliness watch when the whole
    # in-process run was over ("no live rig matches 'labrun' within 10.0 s (live rigs: none)").
    watching = threading.Event()
    declare = lab.RigWatch.__init__

    def declared(self: lab.RigWatch, *args: Any, **kw: Any) -> None:
        declare(self, *args, **kw)
        watching.set()

    monkeypatch.setattr(lab.RigWatch, "__init__", declared)
    codes: list[int] = []
    rec = threading.Thread(target=lambda: codes.append(main(
        ["record", "--from-zenoh", "labrun", "--out", str(tmp_path), "--connect", router])))
    rec.start()
    try:
        assert watching.wait(30), "the recorder never watched for rigs"
        assert main(["run", "--config", str(CONFIG), "--device", "inprocess", "--duration", "2", "--no-display",
                     "--telemetry", "labrun", "--telemetry-connect", router]) == 0
    finally:
        rec.join(60)
    assert codes == [0]
    (run_dir,) = tmp_path.iterdir()
    meta = read_metadata(run_dir)
    assert meta["rig_id"] == "labrun" and meta["records"] > 0 and meta["stop_reason"] == "rig stopped"
    assert "rig stopped: rig labrun:" in capsys.readouterr().out


def test_two_meshed_routers_carry_a_rig_on_one_to_a_viewer_on_the_other(router: str, wait) -> None:
    proc, second = start_router("--mesh", router)  # router B connects to router A
    try:
        rig, viewer = lab_client(router), lab_client(second)
        seen: list[int] = []
        with TelemetryPublisher(rig, "far1", batch=1) as pub, \
                subscribe("far1", lambda s: seen.append(s.sample_index), session=viewer):
            assert wait(pub.has_subscribers)
            assert wait(lambda: list_rigs(viewer, timeout_s=0.5) == ["far1"])
            for i in range(10):
                pub.offer(Sample(i, i, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0))
            assert wait(lambda: len(seen) == 10)
        assert seen == list(range(10))
        rig.close()
        viewer.close()
    finally:
        stop_router(proc)
