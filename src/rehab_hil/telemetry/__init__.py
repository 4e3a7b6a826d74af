"""Telemetry over Eclipse Zenoh: key space, payload codec, publisher, subscriber API, session configs.

Reference: docs/telemetry.md.
"""

from rehab_hil.telemetry.codec import (
    PayloadError,
    StateBatch,
    StateSample,
    decode_json,
    decode_state,
    encode_json,
    encode_state,
)
from rehab_hil.telemetry.keys import RigIdError, RigKeys, validate_rig_id
from rehab_hil.telemetry.publisher import TelemetryPublisher
from rehab_hil.telemetry.session import NetworkConfig, TelemetryConfigError, build_zenoh_config, open_session
from rehab_hil.telemetry.subscriber import (
    Subscription,
    list_rigs,
    query_info,
    send_command,
    subscribe,
    watch_alive,
)

__all__ = [
    "NetworkConfig", "PayloadError", "RigIdError", "RigKeys", "StateBatch", "StateSample", "Subscription",
    "TelemetryConfigError", "TelemetryPublisher", "build_zenoh_config", "decode_json", "decode_state",
    "encode_json", "encode_state", "list_rigs", "open_session", "query_info", "send_command", "subscribe",
    "validate_rig_id", "watch_alive",
]
