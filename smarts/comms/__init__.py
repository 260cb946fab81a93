"""V2V messaging: agents' learned messages and connected traffic's state broadcasts, delivered with
range, channels, latency, loss and bandwidth limits (see ``smarts.comms.network``)."""

from smarts.comms.config import HEADER_BYTES, CommsConfig
from smarts.comms.network import (
    BROADCAST_ROLES,
    TRAFFIC_PAYLOAD_FIELDS,
    Received,
    SenderKind,
    V2VNetwork,
)
from smarts.comms.spaces import (
    MESSAGE_FEATURES,
    message_action_components,
    message_action_space,
    received_observation_space,
    received_to_observation,
    split_message_action,
)

__all__ = [
    "BROADCAST_ROLES",
    "HEADER_BYTES",
    "MESSAGE_FEATURES",
    "TRAFFIC_PAYLOAD_FIELDS",
    "CommsConfig",
    "Received",
    "SenderKind",
    "V2VNetwork",
    "message_action_components",
    "message_action_space",
    "received_observation_space",
    "received_to_observation",
    "split_message_action",
]
