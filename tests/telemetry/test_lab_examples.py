"""The lab files the docs' router commands name are shipped (docs/examples/lab/): the access-control
file is the JSON zenoh's router reads, the object ``command_access_control`` builds for the docs'
users, and ``rehab-hil router`` (a real process on loopback) runs with it and the users file."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from rehab_hil.telemetry import TelemetryConfigError
from rehab_hil.telemetry.access import command_access_control

from .test_lab import lab_client, start_router, stop_router

LAB = Path(__file__).resolve().parents[2] / "docs" / "examples" / "lab"


def test_the_shipped_acl_is_json_and_the_object_the_docs_describe():
    """After a change of ``command_access_control``: ``python scripts/lab_acl_example.py``."""
    doc = json.loads((LAB / "acl.json").read_text())  # plain JSON: the router refuses JSON5
    assert doc == {"access_control": command_access_control(rig_users=["rig"], operators=["alice"],
                                                            viewers=["victor"])}, "run scripts/lab_acl_example.py"


def test_the_router_runs_with_the_shipped_acl_and_users(tmp_path):
    users = dict(line.split(":", 1) for line in (LAB / "users.txt").read_text().split())
    assert (LAB / "victor.pw").read_text().strip() == users["victor"]  # the docs' --password-file
    proc, ep = start_router("--users", str(LAB / "users.txt"), "--access-control", str(LAB / "acl.json"))
    try:
        for user in ("rig", "alice", "victor"):
            lab_client(ep, user=user, password=users[user]).close()
        with pytest.raises(TelemetryConfigError, match="cannot connect"):
            lab_client(ep, user="victor", password="wrong")
    finally:
        assert "router stopped after" in stop_router(proc)
