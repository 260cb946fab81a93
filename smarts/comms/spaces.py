"""The message part of an agent's action and the received-messages part of its observation.

Action: ``message_size`` payload floats in [-payload_bound, payload_bound], followed by one channel
component in [0, channels - 1] (rounded to the nearest channel) when ``config.channel_action`` is
set; otherwise the agent's channel is fixed (``config.agent_channels``, default 0). The agent both
sends and listens on that channel in a step.

Observation (per agent; batch functions add a leading receiver dimension):
- ``messages`` float32[max_messages, 6 + message_size], nearest sender first: 1 if sent by an agent,
  1 if sent by a connected traffic vehicle, the sender's pose when it sent in the receiver's frame
  (dx forward, dy left in m, dheading in rad), age in steps, then the payload (a traffic vehicle's
  payload is ``TRAFFIC_PAYLOAD_FIELDS``).
- ``message_mask`` float32[max_messages]: 1 where a message is present.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import gymnasium
import numpy as np

from smarts.comms.config import CommsConfig
from smarts.comms.network import TRAFFIC_PAYLOAD_BOUND, Received, SenderKind
from smarts.compiled import njit
from smarts.core.errors import ActionError

MESSAGE_FEATURES: tuple[str, ...] = ("from_agent", "from_traffic", "dx", "dy", "dheading", "age")
"""Leading features of one received message; the payload floats follow."""


def message_action_components(config: CommsConfig) -> tuple[str, ...]:
    """Names of the message action's components, in order."""
    names = tuple(f"payload_{i}" for i in range(config.message_size))
    return names + (("channel",) if config.channel_action else ())


def message_action_space(config: CommsConfig) -> gymnasium.spaces.Box:
    """float32 box of the message part of one agent's action (see the module docstring)."""
    bound = config.payload_bound
    low = [-bound] * config.message_size
    high = [bound] * config.message_size
    if config.channel_action:
        low.append(0.0)
        high.append(float(config.channels - 1))
    return gymnasium.spaces.Box(
        low=np.asarray(low, dtype=np.float32), high=np.asarray(high, dtype=np.float32), dtype=np.float32
    )


def split_message_action(
    config: CommsConfig,
    actions: np.ndarray,
    agent_ids: Sequence[str],
    fixed_channels: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Payloads float32[n, message_size] (clipped to the box) and channels int64[n] from the
    message parts ``[n, k]`` of n agents' actions.

    ``fixed_channels`` (int64[n], from ``config.fixed_channels``) is used when the action has no
    channel component. A wrong shape or a non-finite number raises ``ActionError`` naming the agents.
    """
    components = message_action_components(config)
    arr = np.asarray(actions)
    if arr.dtype.kind != "f":
        arr = arr.astype(np.float64)
    expected = (len(agent_ids), len(components))
    if arr.shape != expected:
        raise ActionError(
            f"message actions have shape {arr.shape}; expected {expected}: one row of "
            f"{len(components)} message components ({components[0]}..{components[-1]}) per agent "
            f"{list(agent_ids)}",
            agent_ids,
        )
    n = expected[0]
    payloads = np.empty((n, config.message_size), dtype=np.float32)
    channels = np.zeros(n, dtype=np.int64)
    if _split(arr, config.payload_bound, config.channel_action, config.channels, payloads, channels):
        finite = np.isfinite(arr)
        bad_rows, bad_cols = np.nonzero(~finite)
        problems = [
            f"{agent_ids[r]}: message action component {components[c]} is {arr[r, c]}"
            for r, c in zip(bad_rows.tolist(), bad_cols.tolist())
        ]
        bad_agents = list(dict.fromkeys(agent_ids[r] for r in bad_rows.tolist()))
        raise ActionError("; ".join(problems) + "; expected finite numbers", bad_agents)
    if not config.channel_action and fixed_channels is not None:
        channels[:] = fixed_channels
    return payloads, channels


@njit(nogil=True)
def _split(actions, bound, channel_action, n_channels, payloads, channels):  # pragma: no cover
    """Clip payloads and round channels into the outputs; True if any number is not finite."""
    n, size = payloads.shape
    for i in range(n):
        for p in range(actions.shape[1]):
            if not math.isfinite(actions[i, p]):
                return True
        for p in range(size):
            payloads[i, p] = min(max(actions[i, p], -bound), bound)
        if channel_action:
            c = min(max(actions[i, size], 0.0), n_channels - 1.0)
            channels[i] = np.int64(np.rint(c))
    return False


def _feature_bounds(config: CommsConfig) -> tuple[np.ndarray, np.ndarray]:
    payload = config.payload_bound
    if config.penetration > 0:
        payload = max(payload, TRAFFIC_PAYLOAD_BOUND)
    r = config.range
    low = [0.0, 0.0, -r, -r, -np.pi, 0.0] + [-payload] * config.message_size
    high = [1.0, 1.0, r, r, np.pi, float(config.latency)] + [payload] * config.message_size
    return np.asarray(low, dtype=np.float32), np.asarray(high, dtype=np.float32)


def received_observation_space(config: CommsConfig) -> dict[str, gymnasium.spaces.Box]:
    """One agent's received-messages spaces, to merge into its observation ``Dict`` space."""
    low, high = _feature_bounds(config)
    m = config.max_messages
    return {
        "messages": gymnasium.spaces.Box(
            low=np.broadcast_to(low, (m, low.size)).copy(),
            high=np.broadcast_to(high, (m, high.size)).copy(),
            dtype=np.float32,
        ),
        "message_mask": gymnasium.spaces.Box(low=0.0, high=1.0, shape=(m,), dtype=np.float32),
    }


def received_to_observation(received: Received) -> dict[str, np.ndarray]:
    """Batch observation arrays (leading receiver dimension) from a ``deliver`` result; padding is
    all zeros. The arrays are new, so they stay valid after the next step."""
    n, m, size = received.payload.shape
    messages = np.empty((n, m, len(MESSAGE_FEATURES) + size), dtype=np.float32)
    mask = np.empty((n, m), dtype=np.float32)
    _fill_observation(
        received.sender_kind,
        received.pose,
        received.age,
        received.payload,
        received.mask,
        messages,
        mask,
    )
    return {"messages": messages, "message_mask": mask}


@njit(nogil=True)
def _fill_observation(kind, pose, age, payload, present, messages, mask):  # pragma: no cover
    n, m, size = payload.shape
    for i in range(n):
        for j in range(m):
            row = messages[i, j]
            row[0] = 1.0 if kind[i, j] == _AGENT else 0.0
            row[1] = 1.0 if kind[i, j] == _TRAFFIC else 0.0
            row[2], row[3], row[4] = pose[i, j, 0], pose[i, j, 1], pose[i, j, 2]
            row[5] = age[i, j]
            for p in range(size):
                row[6 + p] = payload[i, j, p]
            mask[i, j] = 1.0 if present[i, j] else 0.0


_AGENT, _TRAFFIC = int(SenderKind.AGENT), int(SenderKind.TRAFFIC)
