"""Zenoh access control for the remote command channel: only named operators may put commands.

The hub enforces it (``NetworkConfig(role="hub", usrpwd_dictionary=..., access_control=...)``); every
session authenticates with user/password. Default deny: rig services may publish telemetry and
receive commands, viewers and operators may subscribe to and query telemetry, and only operators may
put on ``rehab/*/command``. docs/telemetry.md, "Remote commands", shows the resulting JSON5.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

from rehab_hil.telemetry.keys import PREFIX, validate_rig_id

__all__ = ["ALL_MESSAGES", "command_access_control"]

ALL_MESSAGES = ("put", "delete", "declare_subscriber", "query", "reply", "declare_queryable",
                "liveliness_token", "declare_liveliness_subscriber", "liveliness_query")
_READ_IN = ("declare_subscriber", "query", "declare_liveliness_subscriber", "liveliness_query")
_READ_OUT = ("put", "delete", "reply", "liveliness_token")


def _names(kind: str, names: Sequence[str]) -> list[str]:
    out = list(names)
    for n in out:
        if not isinstance(n, str) or not n or ":" in n or any(c.isspace() for c in n):
            raise ValueError(f"{kind} user name {n!r} must be non-empty, without ':' or whitespace")
    return out


def command_access_control(*, rig_users: Sequence[str], operators: Sequence[str] = (),
                           viewers: Sequence[str] = (), rigs: Sequence[str] | None = None) -> dict[str, Any]:
    """The hub's ``access_control`` object: default deny, telemetry readable by viewers and operators,
    commands writable only by ``operators`` (for all rigs, or only the rig ids in ``rigs``)."""
    rig_users, operators, viewers = _names("rig", rig_users), _names("operator", operators), _names("viewer", viewers)
    if not rig_users:
        raise ValueError("at least one rig user is needed (the rig service's zenoh user name)")
    both = set(rig_users) & (set(operators) | set(viewers))
    if both:
        raise ValueError(f"user names {sorted(both)} cannot be both a rig and an operator/viewer")
    # the state publisher's cache, miss detection and liveliness live under the state key's "@adv"
    # suffix (zenoh's AdvancedPublisher), which "**" does not reach: a late viewer's history query
    everything = [f"{PREFIX}/**", f"{PREFIX}/*/state/@adv/**"]
    commands = [f"{PREFIX}/*/command"] if rigs is None else [f"{PREFIX}/{validate_rig_id(r)}/command" for r in rigs]
    rules = [
        {"id": "rig", "messages": list(ALL_MESSAGES), "flows": ["ingress", "egress"], "permission": "allow",
         "key_exprs": everything},
        {"id": "read_requests", "messages": list(_READ_IN), "flows": ["ingress"], "permission": "allow",
         "key_exprs": everything},
        {"id": "read_delivery", "messages": list(_READ_OUT), "flows": ["egress"], "permission": "allow",
         "key_exprs": everything},
        {"id": "command", "messages": ["put"], "flows": ["ingress"], "permission": "allow", "key_exprs": commands},
    ]
    subjects = [{"id": "rigs", "usernames": rig_users}]
    policies = [{"rules": ["rig"], "subjects": ["rigs"]}]
    readers = []
    if operators:
        subjects.append({"id": "operators", "usernames": operators})
        readers.append("operators")
        policies.append({"rules": ["command"], "subjects": ["operators"]})
    if viewers:
        subjects.append({"id": "viewers", "usernames": viewers})
        readers.append("viewers")
    if readers:
        policies.append({"rules": ["read_requests", "read_delivery"], "subjects": readers})
    return {"enabled": True, "default_permission": "deny", "rules": rules, "subjects": subjects,
            "policies": policies}
