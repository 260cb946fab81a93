"""The V2V communication settings of a scenario (its ``comms`` section), checked once at build time.

Every limit here is fixed for an episode so that the message action and the received-messages
observation have fixed shapes.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field, fields
from typing import Annotated, Any

import numpy as np
from pydantic import Field, ValidationError, model_validator

from smarts.core.errors import ScenarioError
from smarts.core.schema import Schema, field_errors, locate

HEADER_BYTES = 16
"""Bytes of a message besides its payload: sender id (4) and sender x, y, heading as float32 (12)."""

PAYLOAD_BYTES_PER_FLOAT = 4  # payload floats travel as float32


def _fail(message: str) -> None:
    raise ScenarioError(message)


class CommsFile(Schema):
    """A scenario's ``comms:`` section as written (every field optional; see :class:`CommsConfig`)."""

    channels: Annotated[int, Field(ge=1)] = Field(
        1, description="Radio channels; a receiver hears only the channel it is tuned to."
    )
    range: Annotated[float, Field(gt=0, allow_inf_nan=False)] = Field(
        100.0, description="m, greatest distance between the sender (when it sent) and the receiver (at delivery)."
    )
    latency: Annotated[int, Field(ge=0)] = Field(
        0, description="Steps between sending and delivery (0: delivered in the step it was sent)."
    )
    loss: Annotated[float, Field(ge=0, lt=1)] = Field(
        0.0, description="Probability that a message is lost on its way to one receiver."
    )
    bandwidth: Annotated[int, Field(ge=1)] | None = Field(
        None, description="Most messages one receiver takes per step (null: no limit besides max_messages)."
    )
    bandwidth_bytes: Annotated[int, Field(ge=1)] | None = Field(
        None, description="Most bytes one receiver takes per step (null: no byte limit)."
    )
    message_size: Annotated[int, Field(ge=1)] = Field(8, description="Floats of payload per message.")
    penetration: Annotated[float, Field(ge=0, le=1)] = Field(
        0.0, description="Fraction of traffic vehicles that are connected and broadcast their state every step."
    )
    max_messages: Annotated[int, Field(ge=1)] = Field(
        8, description="Messages per receiver per step in the observation (its fixed size)."
    )
    traffic_channel: int = Field(0, description="The channel traffic broadcasts on; -1: heard on every channel.")
    channel_action: bool = Field(
        False, description="true: the message action picks the channel each step; false: agent_channels."
    )
    agent_channels: dict[str, int] = Field(
        default_factory=dict, description="Fixed channel per agent id when channel_action is false (default 0)."
    )
    payload_bound: Annotated[float, Field(gt=0, allow_inf_nan=False)] = Field(
        1.0, description="The message action box is [-payload_bound, payload_bound] per payload float."
    )

    @model_validator(mode="after")
    def _fits_the_channels(self) -> CommsFile:
        problems: list[tuple[Any, str]] = []
        last = self.channels - 1
        if not -1 <= self.traffic_channel <= last:
            problems.append(
                (
                    "traffic_channel",
                    f"expected -1 (every channel) or a channel in [0, {last}], got {self.traffic_channel!r}",
                )
            )
        for agent, channel in self.agent_channels.items():
            if not 0 <= channel <= last:
                problems.append((("agent_channels", agent), f"expected a channel in [0, {last}], got {channel!r}"))
        message_bytes = HEADER_BYTES + PAYLOAD_BYTES_PER_FLOAT * self.message_size
        if self.bandwidth_bytes is not None and self.bandwidth_bytes < message_bytes:
            problems.append((
                "bandwidth_bytes",
                f"{self.bandwidth_bytes} bytes cannot hold one message of {message_bytes} bytes ({HEADER_BYTES} "
                f"header + {PAYLOAD_BYTES_PER_FLOAT} x {self.message_size} payload floats)",
            ))  # fmt: skip
        if problems:
            raise field_errors(self, problems)
        return self

    def to_config(self) -> CommsConfig:
        """The validated section as the simulator's dataclass."""
        return CommsConfig(**{f.name: getattr(self, f.name) for f in fields(CommsConfig)})


def _check(values: Mapping[str, Any], where: str) -> CommsFile:
    """``values`` validated as a comms section; every problem raises at once, each ``where.field``."""
    try:
        return CommsFile.model_validate(dict(values))
    except ValidationError as exc:
        lines = []
        for problem in exc.errors():
            path, message = locate(CommsFile, problem)
            lines.append(f"{where}.{path}: {message}" if path else f"{where}: {message}")
        raise ScenarioError("\n".join(lines)) from None


def _plain(value: Any) -> Any:
    """Numpy scalars as the Python numbers they hold, mappings as dicts (values built in code)."""
    if isinstance(value, (np.generic,)):
        return value.item()
    if isinstance(value, Mapping):
        return {k: _plain(v) for k, v in value.items()}
    return value


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
        if not isinstance(self.agent_channels, Mapping):
            _fail(f"comms.agent_channels: expected a mapping of agent id to channel, got {self.agent_channels!r}")
        _check({f.name: _plain(getattr(self, f.name)) for f in fields(self)}, "comms")

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
            _fail(f"{where}.agent_channels: unknown agents {unknown}; the scenario's agents are {list(agent_ids)}")

    def fixed_channels(self, agent_ids: Sequence[str]) -> np.ndarray:
        """int64[n] channel of each agent when the action does not pick one (setup-time helper)."""
        return np.array([self.agent_channels.get(a, 0) for a in agent_ids], dtype=np.int64)

    # ------------------------------------------------------------------ reading
    @classmethod
    def from_dict(cls, data: Mapping[str, Any] | None, where: str = "comms") -> CommsConfig:
        """Build from a scenario's ``comms`` mapping (``CommsFile``); unknown keys and bad values
        raise, every problem at once, each naming ``where.field``."""
        if data is None:
            return cls()
        if not isinstance(data, Mapping):
            _fail(f"{where}: expected a mapping of settings, got {type(data).__name__}")
        return _check(data, where).to_config()
