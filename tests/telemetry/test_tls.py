"""TLS on loopback: a hub with a certificate from a throwaway CA; clients must verify it."""

from __future__ import annotations

import shutil
import subprocess
from pathlib import Path

import pytest

from rehab_hil.protocol import Sample
from rehab_hil.telemetry import NetworkConfig, TelemetryConfigError, TelemetryPublisher, open_session, subscribe
from rehab_hil.telemetry.codec import StateSample

pytestmark = pytest.mark.skipif(shutil.which("openssl") is None, reason="needs the openssl command")


def make_certs(d: Path) -> dict[str, Path]:
    """A CA, a hub certificate for 127.0.0.1 / localhost signed by it, and an unrelated CA (valid one day)."""
    def ssl(*args: str) -> None:
        subprocess.run(["openssl", *args], cwd=d, check=True, capture_output=True)

    ssl("req", "-x509", "-newkey", "rsa:2048", "-nodes", "-keyout", "ca.key", "-out", "ca.pem", "-days", "1",
        "-subj", "/CN=rehab-test-ca")
    ssl("req", "-newkey", "rsa:2048", "-nodes", "-keyout", "hub.key", "-out", "hub.csr", "-subj", "/CN=localhost")
    (d / "ext.cnf").write_text("subjectAltName=DNS:localhost,IP:127.0.0.1\nbasicConstraints=CA:FALSE\n"
                               "extendedKeyUsage=serverAuth,clientAuth\n")
    ssl("x509", "-req", "-in", "hub.csr", "-CA", "ca.pem", "-CAkey", "ca.key", "-CAcreateserial", "-out", "hub.pem",
        "-days", "1", "-extfile", "ext.cnf")
    ssl("req", "-x509", "-newkey", "rsa:2048", "-nodes", "-keyout", "other.key", "-out", "other.pem", "-days", "1",
        "-subj", "/CN=some-other-ca")
    return {"ca": d / "ca.pem", "cert": d / "hub.pem", "key": d / "hub.key", "other_ca": d / "other.pem"}


def test_a_tls_hub_serves_clients_that_trust_its_ca_and_nobody_else(tmp_path: Path, hub_factory, wait) -> None:
    c = make_certs(tmp_path)
    hub, port = hub_factory(tls=True, tls_certificate=c["cert"], tls_private_key=c["key"])
    sessions = []
    try:
        rig = open_session(NetworkConfig(port=port, tls=True, tls_root_ca=c["ca"]))
        viewer = open_session(NetworkConfig(port=port, tls=True, tls_root_ca=c["ca"]))
        sessions += [rig, viewer]
        got: list[StateSample] = []
        with subscribe("tls1", got.append, session=viewer), TelemetryPublisher(rig, "tls1", batch=1) as pub:
            assert wait(pub.has_subscribers)
            pub.offer(Sample(1, 7, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0))
            assert wait(lambda: len(got) == 1)
        assert got[0].sample_index == 7
        with pytest.raises(TelemetryConfigError, match="cannot connect"):  # plain tcp to a TLS port
            sessions.append(open_session(NetworkConfig(port=port)))
        with pytest.raises(TelemetryConfigError, match="cannot connect"):  # a CA that did not sign the hub
            sessions.append(open_session(NetworkConfig(port=port, tls=True, tls_root_ca=c["other_ca"])))
    finally:
        for s in reversed(sessions):
            s.close()
        hub.close()


def test_tls_settings_that_cannot_work_are_refused(tmp_path: Path) -> None:
    ca = tmp_path / "ca.pem"
    ca.write_text("x")
    with pytest.raises(TelemetryConfigError, match="TLS hub needs"):
        NetworkConfig(role="hub", tls=True).validate()
    with pytest.raises(TelemetryConfigError, match="TLS client needs tls_root_ca"):
        NetworkConfig(tls=True).validate()
    with pytest.raises(TelemetryConfigError, match="tls=True is for loopback"):
        NetworkConfig(mode="lab", router=("tls/r:7447",), tls=True, tls_root_ca=ca).validate()
    assert NetworkConfig(tls=True, tls_root_ca=ca, port=9000).endpoints() == ["tls/127.0.0.1:9000"]


