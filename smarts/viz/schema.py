"""What the page accepts from a live env: the two ``/ws/source`` messages, checked field by field.

The server relays only what these models re-serialise, never the text it received, so a page
never sees a field, a type or a value the drawing code does not expect (no NaN, no infinities,
no unknown keys, no lane or vehicle index outside the episode). Recordings' map descriptions
are checked with the same ``Scene`` model. Sizes are bounded twice: by the byte limits in
``smarts.viz.server`` and by the string lengths here.
"""

from __future__ import annotations

from typing import Annotated, Literal

from pydantic import (
    BaseModel,
    ConfigDict,
    Field,
    StringConstraints,
    TypeAdapter,
    ValidationError,
    ValidationInfo,
    model_validator,
)

Num = Annotated[float, Field(strict=True, allow_inf_nan=False)]
OptNum = Num | None
Name = Annotated[str, StringConstraints(max_length=256)]
"""Vehicle, agent, lane, road, signal and event names."""
Text = Annotated[str, StringConstraints(max_length=4096)]
"""Scenario names and map sources."""
Index = Annotated[int, Field(ge=-1)]
Point = tuple[Num, Num]


class _Model(BaseModel):
    model_config = ConfigDict(extra="forbid", strict=True, frozen=True)


class Lane(_Model):
    id: Name
    road: Name
    index: int
    internal: bool
    width: Annotated[float, Field(strict=True, allow_inf_nan=False, ge=0)]
    speed_limit: Num
    length: Num
    points: Annotated[list[Point], Field(min_length=1)]
    successors: list[Index]
    predecessors: list[Index]


class Signal(_Model):
    tls: Name
    link: int
    from_lane: Index
    via_lane: Index
    to_lane: Index
    stop: Point


class Scene(_Model):
    """The map as the page draws it (``smarts.viz.scene.map_scene``)."""

    version: int
    source: Text
    bounds: tuple[Num, Num, Num, Num]
    lanes: list[Lane]
    junctions: list[list[Point]]
    signals: list[Signal]

    @model_validator(mode="after")
    def _indices_in_range(self) -> "Scene":
        n = len(self.lanes)
        for i, lane in enumerate(self.lanes):
            for key in ("successors", "predecessors"):
                if any(not 0 <= j < n for j in getattr(lane, key)):
                    raise ValueError(f"lanes.{i}.{key}: a lane index outside the {n} lanes")
        for i, s in enumerate(self.signals):
            if not (0 <= s.from_lane < n and 0 <= s.to_lane < n and -1 <= s.via_lane < n):
                raise ValueError(f"signals.{i}: a lane index outside the {n} lanes")
        return self


class LiveMeta(_Model):
    """What ``WatchedEnv`` says about a live episode."""

    scenario: Text
    seed: int | None = None
    dt: Annotated[float, Field(strict=True, allow_inf_nan=False, gt=0, le=3600)]
    episode: Annotated[int, Field(ge=0)] = 0
    roles: list[Name] = []
    agent_ids: list[Name]
    live: bool = True
    events: list[Name] | None = None
    action_fields: dict[Name, Annotated[list[Name], Field(max_length=16)]] | None = None


class AgentFrame(_Model):
    vehicle: Name
    action: list[OptNum] | None
    reward: OptNum
    events: Annotated[list[Name], Field(max_length=64)]
    neighbours: list[tuple[OptNum, OptNum, OptNum]]
    waypoints: list[list[tuple[OptNum, OptNum]]]


class Frame(_Model):
    """One live step (``smarts.viz.capture.frame_json``)."""

    step: Annotated[int, Field(ge=0)]
    t: Num
    ids: list[Name]
    x: list[Num]
    y: list[Num]
    h: list[Num]
    speed: list[Num]
    length: list[Num]
    width: list[Num]
    role: list[Annotated[int, Field(ge=0, le=255)]]
    lane: list[Index]
    signals: list[Annotated[int, Field(ge=0, le=255)]]
    agents: dict[Name, AgentFrame]

    @model_validator(mode="after")
    def _consistent(self, info: ValidationInfo) -> "Frame":
        n = len(self.ids)
        for key in ("x", "y", "h", "speed", "length", "width", "role", "lane"):
            if len(getattr(self, key)) != n:
                raise ValueError(f"{key}: {len(getattr(self, key))} values for {n} vehicles")
        ids = set(self.ids)
        for agent, entry in self.agents.items():
            if entry.vehicle not in ids:
                raise ValueError(f"agents.{agent}.vehicle: not one of this frame's vehicles")
        lanes = (info.context or {}).get("lanes")
        if lanes is not None and any(k >= lanes for k in self.lane):
            raise ValueError(f"lane: an index outside the episode's {lanes} lanes")
        signals = (info.context or {}).get("signals")
        if signals is not None and len(self.signals) > signals:
            raise ValueError(f"signals: {len(self.signals)} colours for the episode's {signals} signals")
        return self


class EpisodeMessage(_Model):
    type: Literal["episode"]
    meta: LiveMeta
    scene: Scene


class FrameMessage(_Model):
    type: Literal["frame"]
    frame: Frame


class MessageError(ValueError):
    """A source's message that the server refuses; the text names the field at fault."""


def describe(err: ValidationError, *, tagged: bool = False) -> str:
    """The first problem of ``err`` as ``field.path: what is wrong`` (one line); ``tagged``: the
    first part of the path is a union's tag, which the field path repeats, so it is left out."""
    first = err.errors(include_url=False)[0]
    loc = first["loc"][1:] if tagged and len(first["loc"]) > 1 else first["loc"]
    where = ".".join(str(part) for part in loc)
    msg = first["msg"].removeprefix("Value error, ")
    return f"{where}: {msg}" if where else msg


def parse_message(text: str | bytes, lanes: int | None, signals: int | None) -> EpisodeMessage | FrameMessage:
    """Check one ``/ws/source`` message; a frame is checked against the current episode's ``lanes``
    and ``signals`` counts (None: there is no episode yet, and a frame is refused)."""
    try:
        message = _MESSAGE.validate_json(text, context={"lanes": lanes, "signals": signals})
    except ValidationError as err:
        raise MessageError(describe(err, tagged=True)) from None
    if isinstance(message, FrameMessage) and lanes is None:
        raise MessageError("frame: sent before any episode")
    return message


_MESSAGE: TypeAdapter[EpisodeMessage | FrameMessage] = TypeAdapter(
    Annotated[EpisodeMessage | FrameMessage, Field(discriminator="type")]
)
