from __future__ import annotations

import pytest

from rehab_hil.telemetry.keys import RigIdError, RigKeys, rig_from_key, validate_rig_id


def test_rig_keys_follow_the_documented_key_space() -> None:
    k = RigKeys("bench-1")
    assert (k.state, k.command, k.safety, k.stats, k.alive, k.info) == (
        "rehab/bench-1/state", "rehab/bench-1/command", "rehab/bench-1/safety",
        "rehab/bench-1/stats", "rehab/bench-1/alive", "rehab/bench-1/info")


@pytest.mark.parametrize("rig", ["r1", "lab_A.2", "SMA-wire-03", "0"])
def test_valid_rig_ids_are_accepted(rig: str) -> None:
    assert validate_rig_id(rig) == rig


@pytest.mark.parametrize(("rig", "why"), [
    ("", "empty"), ("a/b", "separator"), ("*", "wildcard"), ("rig**", "wildcard"), ("$rig", "DSL"),
    ("r?x", "selector"), ("r#1", "reserved"), ("with space", "letters, digits"), ("-lead", "starting"),
    ("x" * 64, "1-63"), ("r\u00e9", "letters"),
])
def test_invalid_rig_ids_are_refused_with_the_reason(rig: str, why: str) -> None:
    with pytest.raises(RigIdError, match=why):
        RigKeys(rig)


def test_a_non_string_rig_id_is_refused() -> None:
    with pytest.raises(RigIdError, match="string"):
        validate_rig_id(7)


def test_rig_id_is_recovered_from_a_liveliness_key() -> None:
    assert rig_from_key("rehab/r9/alive") == "r9"
    with pytest.raises(RigIdError):
        rig_from_key("other/r9/alive")
