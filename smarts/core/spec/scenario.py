"""What a scenario holds: map, agents and their missions, events, rewards, traffic
(``smarts.core.spec.traffic``), comms (``smarts.core.spec.comms``), replay
(``smarts.core.spec.replay``) and each agent's sensors (``smarts.core.spec.interface``).

These frozen, validated models are both what a scenario file's sections validate into and what
every layer reads. Types, ranges and choices are the fields' own; checks that span fields or
sections (a mission's start and goal, unique ids, the trip an agent takes over, a followed vehicle,
the agents comms names) are model validators that name the exact field, so every problem of a file
is reported at once, one line each (``file: agents[1].mission.goal.radius: what was expected``).
Reading and writing YAML, and the checks that need the map, live in ``smarts.scenario``.
"""

from __future__ import annotations

import difflib
from dataclasses import dataclass
from pathlib import Path
from typing import Annotated, Any, Literal

from pydantic import AfterValidator, Field, PrivateAttr, ValidationInfo, field_validator, model_validator

from smarts.core.schema import field_errors
from smarts.core.spec.base import MAX_SPEED as MAX_SPEED
from smarts.core.spec.base import Index, NonNegative, Number, Point, Positive, Spec, Speed, Text, given
from smarts.core.spec.comms import CommsConfig
from smarts.core.spec.interface import AgentInterface
from smarts.core.spec.replay import REPLAY_MAP, ReplaySpec
from smarts.core.spec.traffic import TrafficSpec
from smarts.core.vehicle_types import VEHICLE_DIMENSIONS, VehicleType

BUILTIN_PREFIX = "builtin:"
"""A scenario's ``map`` naming a built-in map: ``builtin:<name>``."""
MAP_FILE_SUFFIXES = (".net.xml", ".xodr")
ZOO_PREFIX = "zoo:"
BUILTIN_MAPS_CONTEXT = "builtin_maps"
"""Validation context key: the names of the built-in maps (the scenario reader passes them, so an
unknown ``builtin:<name>`` is reported with the file's other problems)."""

ACTION_SPACES = ("relative_target_pose", "target_pose", "continuous", "lane")
CONTROLLERS = ("direct", "lane_relative")
"""How an agent's actions reach its action space: ``direct`` (the space's own actions) or
``lane_relative`` (target-speed and lane-change commands turned into that space's actions by
``smarts.dynamics.lane_relative``)."""
LANE_RELATIVE_SPACES = ("relative_target_pose", "target_pose", "continuous")
TERMINATION_EVENTS = (
    "collision",
    "off_road",
    "partial_off_road",
    "wrong_way",
    "off_route",
    "reached_goal",
    "not_moving",
    "max_steps",
)
DEFAULT_TERMINATE_ON = ("collision", "off_road", "reached_goal", "max_steps")
MISSION_END_ACTIONS = ("remove", "traffic")
"""What happens to an agent's vehicle when its mission ends: it leaves, or traffic drives it on."""

# What a scenario file may ask for, whatever its map. Checks that need the map (a start speed
# against its lane's speed limit, routes) are in ``smarts.scenario.map_check``.
MAX_EPISODE_STEPS = 10_000_000
"""Steps of one episode (11.6 days of simulated time at 0.1 s)."""
MAX_VEHICLE_CAPACITY = 100_000
"""Rows of the vehicle table (fixed-size arrays allocated at reset)."""
SEED_MAX = 2**64 - 1
"""Seeds run from 0 to 2**64 - 1, as everywhere a seed is given (``smarts.core.simulation``)."""


@dataclass(frozen=True)
class VehicleDimensions:
    length: float
    width: float
    height: float
    mass: float


VEHICLE_TYPES: dict[str, VehicleDimensions] = {
    t.name.lower(): VehicleDimensions(*VEHICLE_DIMENSIONS[t])
    for t in VehicleType
    if t not in (VehicleType.PEDESTRIAN, VehicleType.BICYCLE)
}
"""Typical dimensions (m) and mass (kg) per vehicle type; a scenario may override each one."""


def _locator(value: str) -> str:
    """A zoo locator; only its form is checked here, the zoo resolves it when the env starts."""
    if not value.removeprefix(ZOO_PREFIX) or any(c.isspace() for c in value):
        raise ValueError("expected a zoo locator such as 'zoo:keep-lane' or 'keep-lane'")
    return value


def did_you_mean(name: str, known: Any) -> str:
    hint = difflib.get_close_matches(name, list(known), n=1)
    return f" (did you mean {hint[0]!r}?)" if hint else ""


# ---------------------------------------------------------------------------- agents
class VehicleSpec(Spec):
    """An agent's vehicle: a type's typical dimensions, each one overridable."""

    type: Literal[tuple(VEHICLE_TYPES)] = "passenger"  # type: ignore[valid-type]
    length: Positive | None = Field(None, description="m; null: the type's.")
    width: Positive | None = Field(None, description="m; null: the type's.")
    height: Positive | None = Field(None, description="m; null: the type's.")
    mass: Positive | None = Field(None, description="kg; null: the type's.")

    def dimensions(self) -> VehicleDimensions:
        """The type's defaults with this spec's overrides applied."""
        base = VEHICLE_TYPES[self.type]
        return VehicleDimensions(
            length=base.length if self.length is None else self.length,
            width=base.width if self.width is None else self.width,
            height=base.height if self.height is None else self.height,
            mass=base.mass if self.mass is None else self.mass,
        )


_POSE = ("road", "lane", "offset", "speed", "heading")


class StartSpec(Spec):
    """Where the agent starts: a pose on a lane, or ``take_over: <trip id>`` (a traffic vehicle)."""

    road: Text | None = Field(None, description="Road id; required unless take_over is given.")
    lane: Index = 0
    offset: NonNegative = Field(0.0, description="Metres along the lane from its start.")
    speed: Speed = Field(
        0.0,
        description=f"m/s, 0 to {MAX_SPEED:g}; on the map at most its lane's speed limit times "
        "1.5, and what the action space can drive.",
    )
    heading: Number | None = Field(None, description="Radians; null: along the lane.")
    take_over: Text | None = Field(
        None,
        description="Id of a traffic trip departing at 0 (or, with a replay, a recorded vehicle) whose vehicle "
        "the agent drives from reset on (its pose is that vehicle's, so no road, lane, offset, speed or heading).",
    )

    @model_validator(mode="after")
    def _pose_or_take_over(self) -> StartSpec:
        if self.take_over is not None:
            problems = [
                (key, f"not allowed with take_over: the agent starts as trip {self.take_over!r}'s vehicle, "
                 "where it is and as fast as it goes")
                for key in given(self, *_POSE)
            ]  # fmt: skip
        elif self.road is None:
            problems = [("road", "required field missing (a road id, or give take_over instead)")]
        else:
            problems = []
        if problems:
            raise field_errors(self, problems)
        return self


class GoalSpec(Spec):
    """Exactly one kind of goal: a position with a radius, a road (and lane, offset), or endless."""

    position: Point | None = Field(None, description="[x, y] in metres.")
    radius: Positive = Field(3.0, description="m around position; only with a position goal.")
    road: Text | None = None
    lane: Index | None = Field(None, description="Only with a road goal; null: any lane of the road.")
    offset: NonNegative | None = Field(
        None, description="Metres along the goal lane that must be reached; null: entering the road is enough."
    )
    endless: bool = Field(False, description="true: drive on with no goal.")

    @property
    def kind(self) -> str:
        if self.endless:
            return "endless"
        return "position" if self.position is not None else "road"

    @model_validator(mode="after")
    def _one_kind(self) -> GoalSpec:
        kinds = [k for k in ("position", "road") if getattr(self, k) is not None]
        kinds += ["endless"] if given(self, "endless") else []
        problems: list[tuple[Any, str]] = []
        if len(kinds) != 1:
            got = " and ".join(kinds) if kinds else "none"
            problems.append(((), f"expected exactly one goal kind (position, road or endless: true), got {got}"))
        else:
            for key, needs in (("radius", "position"), ("lane", "road"), ("offset", "road")):
                if getattr(self, key) is not None and given(self, key) and kinds[0] != needs:
                    problems.append((key, f"only allowed with a {needs} goal, not a {kinds[0]} goal"))
            if kinds[0] == "endless" and not self.endless:
                problems.append(("endless", "expected true (or give a position or road goal instead), got False"))
        if problems:
            raise field_errors(self, problems)
        return self


class MissionSpec(Spec):
    """Where an agent starts and where it has to go."""

    start: StartSpec
    goal: GoalSpec
    route_via: list[Text] = Field(default_factory=list, description="Roads the route must pass, in order.")
    on_end: Literal[MISSION_END_ACTIONS] = Field(  # type: ignore[valid-type]
        "remove", description="remove: the vehicle leaves when the mission ends; traffic: traffic drives it on."
    )
    follow: Text | None = Field(
        None,
        description="Id of the vehicle this agent follows (a traffic trip or another agent): the lead of the "
        "following task, seen in the lead observation block and scored by SFD; null: no lead.",
    )


class AgentSpec(Spec):
    """One agent: its action space, vehicle, mission, sensors and (for a social agent) its policy."""

    id: Text = Field(description="Defaults to agent_<index> in a scenario file.")
    mission: MissionSpec = Field(description="Required unless replay.take_over names the agent.")
    action_space: Literal[ACTION_SPACES] = "relative_target_pose"  # type: ignore[valid-type]
    controller: Literal[CONTROLLERS] = Field(  # type: ignore[valid-type]
        "direct",
        description="direct: the action space's own actions; lane_relative: (acceleration, lane change) "
        "commands that smarts.dynamics.lane_relative turns into them.",
    )
    vehicle: VehicleSpec = VehicleSpec()
    policy: Annotated[Text, AfterValidator(_locator)] | None = Field(
        None,
        description="Zoo locator (zoo:keep-lane or keep-lane) of the policy driving this agent inside the "
        "simulator: a social agent, not controlled by the learner; null: a learning agent.",
    )
    interface: AgentInterface | None = Field(None, description="Which sensors the agent has; null: the default.")

    @property
    def is_social(self) -> bool:
        return self.policy is not None

    @model_validator(mode="after")
    def _controller_fits(self) -> AgentSpec:
        if self.controller == "lane_relative" and self.action_space not in LANE_RELATIVE_SPACES:
            raise field_errors(self, [(
                "controller",
                f"lane_relative drives {', '.join(LANE_RELATIVE_SPACES)}; got action_space {self.action_space!r}",
            )])  # fmt: skip
        return self


# ---------------------------------------------------------------------------- events, reward
class EventsSpec(Spec):
    """Which events end an agent's episode, and what counts as not moving."""

    terminate_on: list[Literal[TERMINATION_EVENTS]] = Field(  # type: ignore[valid-type]
        default_factory=lambda: list(DEFAULT_TERMINATE_ON)
    )
    not_moving_seconds: Positive = 60.0
    not_moving_distance: NonNegative = Field(
        1.0, description="A vehicle that moved less than this many metres in not_moving_seconds is not moving."
    )

    @model_validator(mode="after")
    def _distinct(self) -> EventsSpec:
        twice = [
            (("terminate_on", i), f"{name!r} is listed twice")
            for i, name in enumerate(self.terminate_on)
            if name in self.terminate_on[:i]
        ]
        if twice:
            raise field_errors(self, twice)
        return self


class RewardSpec(Spec):
    """The built-in reward's terms."""

    progress_weight: NonNegative = Field(1.0, description="Per metre of progress along the route.")
    collision_penalty: NonNegative = 10.0
    off_road_penalty: NonNegative = 10.0
    goal_bonus: NonNegative = 10.0
    step_penalty: NonNegative = Field(0.0, description="Subtracted every step, to favour reaching the goal sooner.")


# ---------------------------------------------------------------------------- the scenario
class ScenarioSpec(Spec):
    """A whole scenario. Where it was read from (``source``, prefixing every error message) and the
    folder relative map paths are resolved against (``base_dir``) are set by the reader; they are
    not fields, so they take no part in equality and a file cannot set them."""

    name: Text = Field(description="Defaults to the file's name when read from a file.")
    map: Text = Field(
        description="builtin:<name>, 'replay' (a replay dataset's own map) or a .net.xml/.xodr path relative "
        "to the scenario file's folder."
    )
    step_length: Annotated[float, Field(gt=0, le=1, allow_inf_nan=False)] = Field(
        0.1, description="Seconds per step, in (0, 1]."
    )
    episode_steps: Annotated[int, Field(ge=1, le=MAX_EPISODE_STEPS)] = Field(
        1000, description=f"1 to {MAX_EPISODE_STEPS:,}."
    )
    seed: Annotated[int, Field(ge=0, le=SEED_MAX)] = Field(42, description="0 to 2**64 - 1.")
    vehicle_capacity: Annotated[int, Field(ge=1, le=MAX_VEHICLE_CAPACITY)] = Field(
        256,
        description=f"Rows of the vehicle table: agents, traffic and pedestrians at once; at most "
        f"{MAX_VEHICLE_CAPACITY:,}.",
    )
    agents: Annotated[list[AgentSpec], Field(min_length=1)]
    events: EventsSpec = EventsSpec()
    reward: RewardSpec = RewardSpec()
    traffic: TrafficSpec | None = Field(
        None, description="Flows, trips, vehicle types and pedestrians; null: agents only."
    )
    comms: CommsConfig | None = Field(
        None, description="V2V messaging; null: off, the action and observation spaces have no message parts."
    )
    replay: ReplaySpec | None = Field(None, description="Recorded traffic replayed from a dataset; null: none.")

    _source: str = PrivateAttr(default="<dict>")
    _base_dir: Path | None = PrivateAttr(default=None)

    # ------------------------------------------------------------------ where it came from
    @property
    def source(self) -> str:
        """Where the spec was read from; prefixes every error message."""
        return self._source

    @property
    def base_dir(self) -> Path | None:
        """Folder that relative map paths are resolved against (the scenario file's folder)."""
        return self._base_dir

    def located(self, source: str, base_dir: Path | None) -> ScenarioSpec:
        """This spec, noted as read from ``source`` with relative paths under ``base_dir``."""
        self._source, self._base_dir = source, base_dir
        return self

    def __eq__(self, other: object) -> bool:  # where it was read from is not part of the scenario
        return type(other) is type(self) and self.__dict__ == other.__dict__

    __hash__ = None  # type: ignore[assignment]  # agents and traffic are lists

    # ------------------------------------------------------------------ derived
    @property
    def agent_ids(self) -> list[str]:
        return [a.id for a in self.agents]

    @property
    def social_agent_ids(self) -> list[str]:
        """Agents driven by a zoo policy inside the simulator, not by the learner."""
        return [a.id for a in self.agents if a.policy is not None]

    @property
    def builtin_map(self) -> str | None:
        """Name of the built-in map, or None when the map is a file."""
        return self.map[len(BUILTIN_PREFIX) :] if self.map.startswith(BUILTIN_PREFIX) else None

    # ------------------------------------------------------------------ checks
    @field_validator("map")
    @classmethod
    def _map_name(cls, value: str, info: ValidationInfo) -> str:
        if value.startswith(BUILTIN_PREFIX):
            known = (info.context or {}).get(BUILTIN_MAPS_CONTEXT)
            name = value[len(BUILTIN_PREFIX) :]
            if known is not None and name not in known:
                hint = difflib.get_close_matches(name, known, n=1)
                suggestion = f" (did you mean {hint[0]!r}?)" if hint else ""
                raise ValueError(f"unknown built-in map {name!r}{suggestion}; known: {', '.join(sorted(known))}")
        elif value != REPLAY_MAP and not value.endswith(MAP_FILE_SUFFIXES):
            raise ValueError(
                f"expected 'builtin:<name>', {REPLAY_MAP!r} (a replay dataset's own map) or a path ending in "
                f"{' or '.join(MAP_FILE_SUFFIXES)}"
            )
        return value

    @model_validator(mode="before")
    @classmethod
    def _file_defaults(cls, data: Any) -> Any:
        """What a file may leave out: an agent's id (``agent_<index>``) and the mission of an agent
        that takes over a recorded vehicle (its start is that vehicle, its goal endless; the env
        builds the real one from the recording)."""
        if not isinstance(data, dict) or not isinstance(data.get("agents"), list):
            return data
        replay = data.get("replay")
        taken = replay.get("take_over") if isinstance(replay, dict) else getattr(replay, "take_over", None)
        taken = taken if isinstance(taken, dict) else {}
        agents = []
        for i, agent in enumerate(data["agents"]):
            if isinstance(agent, dict):
                if agent.get("id") is None:
                    agent = {**agent, "id": f"agent_{i}"}
                vehicle = taken.get(agent["id"]) if isinstance(agent["id"], str) else None
                if vehicle is not None and agent.get("mission") is None:
                    mission = {"start": {"take_over": str(vehicle).strip()}, "goal": {"endless": True}}
                    agent = {**agent, "mission": mission}
            agents.append(agent)
        return {**data, "agents": agents}

    @model_validator(mode="after")
    def _consistent(self) -> ScenarioSpec:
        ids = self.agent_ids
        problems: list[tuple[Any, str]] = []
        if self.vehicle_capacity < len(ids):
            problems.append((
                "vehicle_capacity", f"expected at least the number of agents ({len(ids)}), got {self.vehicle_capacity}"
            ))  # fmt: skip
        first: dict[str, int] = {}
        for i, agent_id in enumerate(ids):
            if agent_id in first:
                problems.append(
                    (("agents", i, "id"), f"duplicate agent id {agent_id!r} (also agents[{first[agent_id]}])")
                )
            first.setdefault(agent_id, i)
        problems += self._agents_and_replay(ids)
        problems += self._agents_and_traffic(first)
        if self.comms is not None:
            unknown = sorted(set(self.comms.agent_channels) - set(ids))
            if unknown:
                problems.append((
                    ("comms", "agent_channels"), f"unknown agents {unknown}; the scenario's agents are {ids}"
                ))  # fmt: skip
        if problems:
            raise field_errors(self, problems)
        return self

    def _replayed(self, agent: AgentSpec) -> bool:
        """Whether the agent takes over a recorded vehicle (its mission stands for the track's)."""
        taken = {} if self.replay is None else self.replay.take_over
        start = agent.mission.start
        return agent.id in taken and start.take_over == taken[agent.id] and agent.mission.goal.endless

    def _agents_and_replay(self, ids: list[str]) -> list[tuple[Any, str]]:
        """Agents taking over recorded vehicles have no mission of their own."""
        taken = {} if self.replay is None else self.replay.take_over
        problems: list[tuple[Any, str]] = []
        for i, agent in enumerate(self.agents):
            if ids[i] in taken and not self._replayed(agent):
                problems.append((("agents", i, "mission"), f"not allowed: replay.take_over gives agent {ids[i]!r} "
                                 f"recorded vehicle {taken[ids[i]]!r}, whose track sets its start and goal"))  # fmt: skip
        for agent_id in taken:
            if agent_id not in ids:
                problems.append((("replay", "take_over", agent_id), f"unknown agent {agent_id!r}{did_you_mean(agent_id, ids)}; "
                                 f"the scenario's agents are {ids}"))  # fmt: skip
        twice = [v for i, v in enumerate(taken.values()) if v in list(taken.values())[:i]]
        for vehicle in dict.fromkeys(twice):
            problems.append(
                (("replay", "take_over"), f"recorded vehicle {vehicle!r} is taken over by more than one agent")
            )
        if self.map == REPLAY_MAP and (self.replay is None or self.replay.format == "ngsim"):
            problems.append(("map", f"{REPLAY_MAP!r} is the map of an argoverse2 or waymo replay; "
                             + ("the scenario has no replay section" if self.replay is None else
                                "NGSIM has no map of its own: name its .net.xml")))  # fmt: skip
        if self.map == REPLAY_MAP and self.traffic is not None and self.traffic.engine == "sumo":
            problems.append(
                (("traffic", "engine"), f"sumo needs a SUMO network; map {REPLAY_MAP!r} has none (use builtin)")
            )
        return problems

    def _agents_and_traffic(self, agent_index: dict[str, int]) -> list[tuple[Any, str]]:
        """Checks that span both sections: taken-over trips, hand-back, leads, clashing vehicle ids."""
        traffic = self.traffic
        trips = {} if traffic is None else {t.id: t for t in traffic.trips}
        problems: list[tuple[Any, str]] = []
        taken_by: dict[str, int] = {}
        for i, agent in enumerate(self.agents):
            if self._replayed(agent):  # takes over a recorded vehicle (checked with the replay)
                continue
            mission = agent.mission
            trip_id = mission.start.take_over
            where = ("agents", i, "mission", "start", "take_over")
            if trip_id is None:
                pass
            elif traffic is None:
                problems.append((where, f"no trip {trip_id!r} to take over: the scenario has no traffic section"))
            elif trip_id not in trips:
                problems.append((where, f"unknown trip {trip_id!r}{did_you_mean(trip_id, trips)}; "
                                 f"traffic.trips: {', '.join(trips) or 'none'}"))  # fmt: skip
            elif trips[trip_id].depart != 0.0:
                problems.append((where, f"trip {trip_id!r} departs at {trips[trip_id].depart:g} s; only a trip "
                                 "departing at 0 exists at reset to be taken over"))  # fmt: skip
            elif trip_id in taken_by:
                problems.append((where, f"trip {trip_id!r} is already taken over by agents[{taken_by[trip_id]}]"))
            else:
                taken_by[trip_id] = i
            if mission.on_end == "traffic" and traffic is None:
                problems.append((("agents", i, "mission", "on_end"), "'traffic' hands the vehicle to traffic, but "
                                 "the scenario has no traffic section"))  # fmt: skip
        ids = self.agent_ids
        for i, agent in enumerate(self.agents):
            if self._replayed(agent):
                continue
            lead = agent.mission.follow
            where = ("agents", i, "mission", "follow")
            if lead is None:
                continue
            if lead == ids[i]:
                problems.append((where, "an agent cannot follow itself"))
            elif lead not in trips and lead not in agent_index:
                known = [*trips, *agent_index]
                problems.append((where, f"no vehicle {lead!r} to follow{did_you_mean(lead, known)}; "
                                 f"traffic.trips and agents: {', '.join(known) or 'none'}"))  # fmt: skip
        for j, trip in enumerate(traffic.trips if traffic is not None else []):
            if trip.id in agent_index:
                problems.append((("traffic", "trips", j, "id"), f"{trip.id!r} is also the id of "
                                 f"agents[{agent_index[trip.id]}]; vehicle ids must be unique"))  # fmt: skip
        return problems
