"""The V2V communication settings of a scenario (its ``comms`` section), checked once at build time.

Every limit here is fixed for an episode so that the message action and the received-messages
observation have fixed shapes.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field, fields
from typing import Any

import numpy as np

from smarts.core.errors import ScenarioError

HEADER_BYTES = 16
"""Bytes of a message besides its payload: sender id (4) and sender x, y, heading as float32 (12)."""

PAYLOAD_BYTES_PER_FLOAT = 4  # payload floats travel as float32


def _fail(message: str) -> None:
    raise ScenarioError(message)


def _is_int(value: Any) -> bool:
    return isinstance(value, (int, np.integer)) and not isinstance(value, (bool, np.bool_))


def _is_number(value: Any) -> bool:
    return isinstance(value, (int, float, np.integer, np.floating)) and not isinstance(
        value, (bool, np.bool_)
    )


@dataclass(frozen=True)
class CommsConfig:
    """How agents and connected traffic vehicles talk to each other.

    channels: number of radio channels; a receiver hears only the channel it is tuned to.
    range: m, greatest distance between the sender (where it was when it sent) and the receiver
        (where it is at delivery).
    latency: steps between sending and delivery (0: delivered in the step it was sent).
    loss: probability that a message is lost on its way to one receiver, independently per
        (message, receiver).
    bandwidth: most messages one receiver takes per step (None: no limit besides max_messages).
    bandwidth_bytes: most bytes one receiver takes per step, each message being
        ``HEADER_BYTES + 4 * message_size`` bytes (None: no byte limit).
    message_size: floats of payload per message.
    penetration: fraction of traffic vehicles that are connected: each broadcasts its state every
        step (the pick is a seeded draw per vehicle id, so a vehicle is connected for its whole life).
    max_messages: messages per receiver per step in the observation (its fixed size).
    traffic_channel: the channel traffic broadcasts on; -1 = heard on every channel.
    channel_action: True: the message action has a channel component (the agent sends and listens
        on the channel it picks each step); False: each agent keeps its channel from
        ``agent_channels`` (default 0).
    agent_channels: fixed channel per agent id when ``channel_action`` is False.
    payload_bound: the message action box is [-payload_bound, payload_bound] per payload float;
        sent payloads are clipped to it.
    """

    channels: int = 1
    range: float = 100.0
    latency: int = 0
    loss: float = 0.0
    bandwidth: int | None = None
    bandwidth_bytes: int | None = None
    message_size: int = 8
    penetration: float = 0.0
    max_messages: int = 8
    traffic_channel: int = 0
    channel_action: bool = False
    agent_channels: Mapping[str, int] = field(default_factory=dict, hash=False)
    payload_bound: float = 1.0

    def __post_init__(self) -> None:
        self._validate("comms")

    def _validate(self, where: str) -> None:
        def positive_int(name: str, minimum: int, optional: bool = False) -> None:
            value = getattr(self, name)
            if optional and value is None:
                return
            if not _is_int(value) or value < minimum:
                extra = " or null" if optional else ""
                _fail(f"{where}.{name}: expected an integer >= {minimum}{extra}, got {value!r}")

        positive_int("channels", 1)
        positive_int("latency", 0)
        positive_int("message_size", 1)
        positive_int("max_messages", 1)
        positive_int("bandwidth", 1, optional=True)
        positive_int("bandwidth_bytes", 1, optional=True)
        if not (_is_number(self.range) and math.isfinite(self.range) and self.range > 0):
            _fail(f"{where}.range: expected a positive number of metres, got {self.range!r}")
        if not (_is_number(self.loss) and 0.0 <= self.loss < 1.0):
            _fail(f"{where}.loss: expected a probability in [0, 1), got {self.loss!r}")
        if not (_is_number(self.penetration) and 0.0 <= self.penetration <= 1.0):
            _fail(f"{where}.penetration: expected a fraction in [0, 1], got {self.penetration!r}")
        if not (
            _is_number(self.payload_bound)
            and math.isfinite(self.payload_bound)
            and self.payload_bound > 0
        ):
            _fail(f"{where}.payload_bound: expected a positive number, got {self.payload_bound!r}")
        if not _is_int(self.traffic_channel) or not -1 <= self.traffic_channel < self.channels:
            _fail(
                f"{where}.traffic_channel: expected -1 (every channel) or a channel in "
                f"[0, {self.channels - 1}], got {self.traffic_channel!r}"
            )
        if not isinstance(self.channel_action, (bool, np.bool_)):
            _fail(f"{where}.channel_action: expected true or false, got {self.channel_action!r}")
        if self.bandwidth_bytes is not None and self.bandwidth_bytes < self.message_bytes:
            _fail(
                f"{where}.bandwidth_bytes: {self.bandwidth_bytes} bytes cannot hold one message of "
                f"{self.message_bytes} bytes ({HEADER_BYTES} header + {PAYLOAD_BYTES_PER_FLOAT} x "
                f"{self.message_size} payload floats)"
            )
        if not isinstance(self.agent_channels, Mapping):
            _fail(
                f"{where}.agent_channels: expected a mapping of agent id to channel, "
                f"got {self.agent_channels!r}"
            )
        for agent, channel in self.agent_channels.items():
            if not isinstance(agent, str):
                _fail(f"{where}.agent_channels: agent ids must be strings, got {agent!r}")
            if not _is_int(channel) or not 0 <= channel < self.channels:
                _fail(
                    f"{where}.agent_channels.{agent}: expected a channel in "
                    f"[0, {self.channels - 1}], got {channel!r}"
                )

    # ------------------------------------------------------------------ derived sizes
    @property
    def message_bytes(self) -> int:
        return HEADER_BYTES + PAYLOAD_BYTES_PER_FLOAT * self.message_size

    @property
    def receive_limit(self) -> int:
        """Most messages one receiver gets per step: the tightest of the three limits."""
        limit = self.max_messages
        if self.bandwidth is not None:
            limit = min(limit, self.bandwidth)
        if self.bandwidth_bytes is not None:
            limit = min(limit, self.bandwidth_bytes // self.message_bytes)
        return limit

    # ------------------------------------------------------------------ channels of agents
    def check_agents(self, agent_ids: Sequence[str], where: str = "comms") -> None:
        """Raise if ``agent_channels`` names an agent the scenario does not have."""
        unknown = sorted(set(self.agent_channels) - set(agent_ids))
        if unknown:
            _fail(
                f"{where}.agent_channels: unknown agents {unknown}; the scenario's agents are "
                f"{list(agent_ids)}"
            )

    def fixed_channels(self, agent_ids: Sequence[str]) -> np.ndarray:
        """int64[n] channel of each agent when the action does not pick one (setup-time helper)."""
        return np.array([self.agent_channels.get(a, 0) for a in agent_ids], dtype=np.int64)

    # ------------------------------------------------------------------ reading
    @classmethod
    def from_dict(cls, data: Mapping[str, Any] | None, where: str = "comms") -> CommsConfig:
        """Build from a scenario's ``comms`` mapping; unknown keys and bad values name the field."""
        if data is None:
            return cls()
        if not isinstance(data, Mapping):
            _fail(f"{where}: expected a mapping of settings, got {type(data).__name__}")
        known = [f.name for f in fields(cls)]
        unknown = [k for k in data if k not in known]
        if unknown:
            _fail(f"{where}: unknown keys {unknown}; expected some of {known}")
        values = dict(data)
        if isinstance(values.get("agent_channels"), Mapping):
            values["agent_channels"] = dict(values["agent_channels"])
        config = object.__new__(cls)
        for f in fields(cls):
            default = f.default_factory() if callable(f.default_factory) else f.default
            object.__setattr__(config, f.name, values.get(f.name, default))
        config._validate(where)
        return config
