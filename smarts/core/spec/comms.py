"""The V2V communication settings of a scenario (its ``comms`` section), checked once at build time.

Every limit here is fixed for an episode so that the message action and the received-messages
observation have fixed shapes. Built in code, a bad value raises ``ScenarioError`` naming
``comms.<field>``.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Annotated, Any

import numpy as np
from pydantic import Field, ValidationError, model_validator

from smarts.core.errors import ScenarioError
from smarts.core.schema import field_errors, locate
from smarts.core.spec.base import Spec

HEADER_BYTES = 16
"""Bytes of a message besides its payload: sender id (4) and sender x, y, heading as float32 (12)."""

PAYLOAD_BYTES_PER_FLOAT = 4  # payload floats travel as float32


def comms_problem(exc: ValidationError, where: str) -> ScenarioError:
    """Every problem of ``exc`` at once, one line each, naming ``where.field``."""
    lines = []
    for problem in exc.errors():
        path, message = locate(CommsConfig, problem)
        lines.append(f"{where}.{path}: {message}" if path else f"{where}: {message}")
    return ScenarioError("\n".join(lines))


class CommsConfig(Spec):
    """How agents and connected traffic vehicles talk to each other (every field optional)."""

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
        0.0, description="Probability that a message is lost on its way to one receiver (independently per receiver)."
    )
    bandwidth: Annotated[int, Field(ge=1)] | None = Field(
        None, description="Most messages one receiver takes per step (null: no limit besides max_messages)."
    )
    bandwidth_bytes: Annotated[int, Field(ge=1)] | None = Field(
        None,
        description="Most bytes one receiver takes per step, each message being HEADER_BYTES + 4 * message_size "
        "bytes (null: no byte limit).",
    )
    message_size: Annotated[int, Field(ge=1)] = Field(8, description="Floats of payload per message.")
    penetration: Annotated[float, Field(ge=0, le=1)] = Field(
        0.0,
        description="Fraction of traffic vehicles that are connected and broadcast their state every step (a "
        "seeded draw per vehicle id, so a vehicle is connected for its whole life).",
    )
    max_messages: Annotated[int, Field(ge=1)] = Field(
        8, description="Messages per receiver per step in the observation (its fixed size)."
    )
    traffic_channel: int = Field(0, description="The channel traffic broadcasts on; -1: heard on every channel.")
    channel_action: bool = Field(
        False,
        description="true: the message action picks the channel each step (the agent sends and listens on it); "
        "false: each agent keeps its channel from agent_channels.",
    )
    agent_channels: dict[str, int] = Field(
        default_factory=dict, description="Fixed channel per agent id when channel_action is false (default 0)."
    )
    payload_bound: Annotated[float, Field(gt=0, allow_inf_nan=False)] = Field(
        1.0,
        description="The message action box is [-payload_bound, payload_bound] per payload float; sent payloads "
        "are clipped to it.",
    )

    @classmethod
    def code_error(cls, exc: ValidationError) -> Exception:
        return comms_problem(exc, "comms")

    @model_validator(mode="after")
    def _fits_the_channels(self) -> CommsConfig:
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

    def __hash__(self) -> int:  # the channel mapping is a dict: hash its items
        values = tuple(v if not isinstance(v, dict) else tuple(sorted(v.items())) for v in self.__dict__.values())
        return hash((type(self), values))

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
            raise ScenarioError(
                f"{where}.agent_channels: unknown agents {unknown}; the scenario's agents are {list(agent_ids)}"
            )

    def fixed_channels(self, agent_ids: Sequence[str]) -> np.ndarray:
        """int64[n] channel of each agent when the action does not pick one (setup-time helper)."""
        return np.array([self.agent_channels.get(a, 0) for a in agent_ids], dtype=np.int64)

    # ------------------------------------------------------------------ reading
    @classmethod
    def from_dict(cls, data: Mapping[str, Any] | None, where: str = "comms") -> CommsConfig:
        """Build from a scenario's ``comms`` mapping; unknown keys and bad values raise, every
        problem at once, each naming ``where.field``."""
        if data is None:
            return cls()
        if not isinstance(data, Mapping):
            raise ScenarioError(f"{where}: expected a mapping of settings, got {type(data).__name__}")
        try:
            return cls.model_validate(dict(data))
        except ValidationError as exc:
            raise comms_problem(exc, where) from None
