"""The telemetry key space: every zenoh key a rig uses, built from one validated rig id.

Keys live under ``rehab/<rig_id>/``; docs/telemetry.md is the reference. A rig id is exactly one
key-expression chunk, so wildcards and separators are refused with a message saying why.
"""

from __future__ import annotations

import re
from dataclasses import dataclass

import zenoh

__all__ = ["PREFIX", "RigIdError", "RigKeys", "rig_from_key", "validate_rig_id"]

PREFIX = "rehab"
# conservative subset of zenoh's chunk grammar: no '/', '*', '$', '?', '#', whitespace or unicode
_RIG_ID = re.compile(r"^[A-Za-z0-9][A-Za-z0-9_.\-]{0,62}$")


class RigIdError(ValueError):
    """A rig id that is not a single valid zenoh key-expression chunk."""


def validate_rig_id(rig_id: object) -> str:
    """Return ``rig_id`` if it is one safe key-expression chunk, else raise ``RigIdError`` saying why."""
    if not isinstance(rig_id, str):
        raise RigIdError(f"rig id must be a string, got {type(rig_id).__name__}")
    if not rig_id:
        raise RigIdError("rig id must not be empty")
    for ch, why in (("/", "a key separator"), ("*", "a zenoh wildcard"), ("$", "zenoh's DSL marker"),
                    ("?", "a selector separator"), ("#", "reserved by zenoh")):
        if ch in rig_id:
            raise RigIdError(f"rig id {rig_id!r} contains {ch!r} ({why}); use letters, digits, '_', '-', '.'")
    if not _RIG_ID.match(rig_id):
        raise RigIdError(f"rig id {rig_id!r} must be 1-63 characters of letters, digits, '_', '-', '.' "
                         "starting with a letter or digit")
    try:
        zenoh.KeyExpr(f"{PREFIX}/{rig_id}/state")
    except zenoh.ZError as e:  # pragma: no cover - the regex is stricter than zenoh
        raise RigIdError(f"rig id {rig_id!r} is not a valid zenoh key chunk: {e}") from None
    return rig_id


@dataclass(frozen=True)
class RigKeys:
    """The keys of one rig: samples, commands, safety events, 1 Hz stats, liveliness, info queryable."""

    rig_id: str

    def __post_init__(self) -> None:
        validate_rig_id(self.rig_id)

    @property
    def base(self) -> str:
        return f"{PREFIX}/{self.rig_id}"

    @property
    def state(self) -> str:
        return f"{self.base}/state"

    @property
    def command(self) -> str:
        return f"{self.base}/command"

    @property
    def safety(self) -> str:
        return f"{self.base}/safety"

    @property
    def stats(self) -> str:
        return f"{self.base}/stats"

    @property
    def alive(self) -> str:
        return f"{self.base}/alive"

    @property
    def info(self) -> str:
        return f"{self.base}/info"

    @property
    def twin(self) -> str:
        """The live twin's predictions, residuals and model-mismatch events (JSON)."""
        return f"{self.base}/twin"

    @staticmethod
    def any_alive() -> str:
        """Liveliness key expression matching every rig (used to list running rigs)."""
        return f"{PREFIX}/*/alive"


def rig_from_key(key: str) -> str:
    """The rig id of a ``rehab/<rig_id>/...`` key (e.g. a liveliness token), else ``RigIdError``."""
    parts = str(key).split("/")
    if len(parts) < 3 or parts[0] != PREFIX:
        raise RigIdError(f"{key!r} is not a rehab/<rig_id>/... key")
    return validate_rig_id(parts[1])
