"""Reading a scenario: YAML or a plain mapping into the spec dataclasses (``smarts.core.spec``),
strictly validated through the project's config schema (``smarts.core.schema``).

The file layout is a set of schema models: :class:`ScenarioFile` and its sections (agents with their
mission, vehicle and interface, events, reward, traffic, comms). The interface and comms sections are
owned by their packages (``smarts.sensors.interface.InterfaceFile``, ``smarts.comms.config.CommsFile``)
and composed here. Types, ranges and choices are the fields' own; checks that span fields or sections
(a mission's start and goal, unique ids, the trip an agent takes over, a followed vehicle, the agents
comms names) are model validators that name the exact field. Every problem is reported at once, one
line each: ``file: agents[1].mission.goal.radius: what was expected``, with a did-you-mean for a
misspelt key. The validated models are then turned into the plain dataclasses the simulator reads.
"""

from __future__ import annotations

import difflib
import os
from pathlib import Path
from typing import Annotated, Any, Literal

import yaml
from pydantic import AfterValidator, Field, PlainValidator, model_validator

from smarts.comms.config import CommsFile
from smarts.core.errors import ScenarioError
from smarts.core.schema import Schema, field_errors, validate
from smarts.core.spec.replay import REPLAY_MAP
from smarts.core.spec.scenario import (
    ACTION_SPACES,
    BUILTIN_PREFIX,
    CONTROLLERS,
    DEFAULT_TERMINATE_ON,
    LANE_RELATIVE_SPACES,
    MISSION_END_ACTIONS,
    TERMINATION_EVENTS,
    VEHICLE_TYPES,
    AgentSpec,
    EventsSpec,
    GoalSpec,
    MissionSpec,
    RewardSpec,
    ScenarioSpec,
    StartSpec,
    VehicleSpec,
)
from smarts.core.spec.traffic import (
    DEFAULT_VEHICLE_TYPES,
    DENSITY_LEVELS,
    DEPART_LANES,
    DEPART_SPEEDS,
    TRAFFIC_ENGINES,
    TRAFFIC_VEHICLE_BASES,
    FlowSpec,
    PedestrianFlowSpec,
    TrafficSpec,
    TripSpec,
    VehicleTypeSpec,
)
from smarts.scenario.builtin_maps import BUILTIN_MAPS
from smarts.scenario.replay import ReplayFile
from smarts.sensors.interface import InterfaceFile

MAP_FILE_SUFFIXES = (".net.xml", ".xodr")
ZOO_PREFIX = "zoo:"

# ---------------------------------------------------------------------------- physical bounds
# What a scenario file may ask for, whatever its map. Checks that need the map (a start speed
# against its lane's speed limit, routes) are in ``smarts.scenario.map_check``.
MAX_SPEED = 70.0
"""m/s (252 km/h): the most a start speed, a traffic depart speed or a vehicle type's max_speed
may be. No road vehicle the simulator models goes faster; a larger number is a unit mistake."""
MAX_WALKING_SPEED = 10.0
"""m/s: the most a pedestrian flow's walking speed may be."""
MAX_FLOW_RATE = 10_000.0
"""Vehicles (or people) per hour of one flow: a departure every 0.36 s, more than four lanes
carry. Heavier traffic is several flows (SUMO refuses rates whose departures are closer than it
can time, with an error that names no field)."""
MAX_EPISODE_STEPS = 10_000_000
"""Steps of one episode (11.6 days of simulated time at 0.1 s)."""
MAX_TIME = 1e7
"""s: the latest a flow may begin or end and a trip depart (the longest episode at 1 s steps)."""
MAX_VEHICLE_CAPACITY = 100_000
"""Rows of the vehicle table (fixed-size arrays allocated at reset)."""
SEED_MAX = 2**64 - 1
"""Seeds run from 0 to 2**64 - 1, as everywhere a seed is given (``smarts.core.simulation``)."""


def read_scenario(
    data: Any,
    source: str = "<dict>",
    base_dir: str | os.PathLike | None = None,
    spec_class: type[ScenarioSpec] = ScenarioSpec,
) -> ScenarioSpec:
    """Validate a plain mapping (as loaded from YAML) into a ``spec_class`` instance.

    ``source`` prefixes error messages; a relative map path is resolved against ``base_dir``
    (the current directory when None).
    """
    folder = None if base_dir is None else Path(base_dir)
    scenario = validate(ScenarioFile, data, source, ScenarioError)
    if not scenario.map.startswith(BUILTIN_PREFIX) and scenario.map != REPLAY_MAP:
        path = resolve_map_file(scenario.map, folder)
        if not path.is_file():
            raise ScenarioError(f"{source}: map: map file {str(path)!r} does not exist")
    return scenario.to_spec(spec_class, source, folder)


def read_scenario_file(path: str | os.PathLike, spec_class: type[ScenarioSpec] = ScenarioSpec) -> ScenarioSpec:
    """Read and validate a scenario YAML file; its name defaults to the file's name."""
    path = Path(path)
    source = str(path)
    try:
        text = path.read_text(encoding="utf-8")
    except OSError as exc:
        raise ScenarioError(f"{source}: cannot read scenario file: {exc.strerror or exc}") from None
    except UnicodeDecodeError as exc:
        raise ScenarioError(
            f"{source}: not a YAML text file (not UTF-8: byte {exc.object[exc.start]:#04x} at offset {exc.start})"
        ) from None
    try:
        data = yaml.safe_load(text)
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        where = f" at line {mark.line + 1}, column {mark.column + 1}" if mark else ""
        problem = getattr(exc, "problem", None) or str(exc)
        raise ScenarioError(f"{source}: invalid YAML{where}: {problem}") from None
    if data is None:  # an empty file: report its missing fields, not a missing name
        data = {}
    if isinstance(data, dict) and "name" not in data:
        data = {"name": path.name.split(".")[0], **data}
    return read_scenario(data, source, path.parent, spec_class)


def resolve_map_file(map_value: str, base_dir: Path | None) -> Path:
    """A map file named by a scenario: relative paths are resolved against ``base_dir`` (the
    scenario file's folder; the current directory when None)."""
    path = Path(map_value).expanduser()
    if not path.is_absolute():
        path = (base_dir if base_dir is not None else Path.cwd()) / path
    return path


# ---------------------------------------------------------------------------- value types
def _non_blank(value: str) -> str:
    if not value.strip():
        raise ValueError("expected a non-empty string")
    return value


def _map_name(value: str) -> str:
    if value.startswith(BUILTIN_PREFIX):
        name = value[len(BUILTIN_PREFIX) :]
        if name not in BUILTIN_MAPS:
            hint = difflib.get_close_matches(name, BUILTIN_MAPS, n=1)
            suggestion = f" (did you mean {hint[0]!r}?)" if hint else ""
            raise ValueError(f"unknown built-in map {name!r}{suggestion}; known: {', '.join(sorted(BUILTIN_MAPS))}")
    elif value != REPLAY_MAP and not value.endswith(MAP_FILE_SUFFIXES):
        raise ValueError(
            f"expected 'builtin:<name>', {REPLAY_MAP!r} (a replay dataset's own map) or a path ending in "
            f"{' or '.join(MAP_FILE_SUFFIXES)}"
        )
    return value


def _locator(value: str) -> str:
    """A zoo locator; only its form is checked here, the zoo resolves it when the env starts."""
    if not value.removeprefix(ZOO_PREFIX) or any(c.isspace() for c in value):
        raise ValueError("expected a zoo locator such as 'zoo:keep-lane' or 'keep-lane'")
    return value


def _depart_lane(value: Any) -> str | int:
    if (isinstance(value, str) and value in DEPART_LANES) or (
        isinstance(value, int) and not isinstance(value, bool) and value >= 0
    ):
        return value
    raise ValueError(f"expected one of {', '.join(DEPART_LANES)} or a lane index (an integer >= 0)")


def _depart_speed(value: Any) -> str | float:
    if isinstance(value, str) and value in DEPART_SPEEDS:
        return value
    if isinstance(value, (int, float)) and not isinstance(value, bool) and 0 <= value <= MAX_SPEED:
        return float(value)
    raise ValueError(f"expected one of {', '.join(DEPART_SPEEDS)} or a speed in m/s from 0 to {MAX_SPEED:g}")


Text = Annotated[str, AfterValidator(_non_blank)]
"""A non-empty string (an id, a road)."""
Number = Annotated[float, Field(allow_inf_nan=False)]
Positive = Annotated[float, Field(gt=0, allow_inf_nan=False)]
NonNegative = Annotated[float, Field(ge=0, allow_inf_nan=False)]
Speed = Annotated[float, Field(ge=0, le=MAX_SPEED, allow_inf_nan=False)]
"""m/s, from 0 to ``MAX_SPEED``."""
Time = Annotated[float, Field(ge=0, le=MAX_TIME, allow_inf_nan=False)]
"""s from the start of the episode, up to ``MAX_TIME``."""
Rate = Annotated[float, Field(gt=0, le=MAX_FLOW_RATE, allow_inf_nan=False)]
"""Per hour, up to ``MAX_FLOW_RATE``."""
Index = Annotated[int, Field(ge=0)]
DepartLane = Annotated[str | int, PlainValidator(_depart_lane, json_schema_input_type=str | int)]
DepartSpeed = Annotated[str | float, PlainValidator(_depart_speed, json_schema_input_type=str | float)]

_VTYPE = VehicleTypeSpec("")
_REWARD = RewardSpec()
_EVENTS = EventsSpec()


def _given(model: Schema, *names: str) -> list[str]:
    """Which of ``names`` the file gave (explicitly, null included)."""
    return [name for name in names if name in model.model_fields_set]


# ---------------------------------------------------------------------------- agents
class VehicleFile(Schema):
    """An agent's vehicle: a type's typical dimensions, each one overridable."""

    type: Literal[tuple(VEHICLE_TYPES)] = "passenger"  # type: ignore[valid-type]
    length: Positive | None = Field(None, description="m; null: the type's.")
    width: Positive | None = Field(None, description="m; null: the type's.")
    height: Positive | None = Field(None, description="m; null: the type's.")
    mass: Positive | None = Field(None, description="kg; null: the type's.")

    def to_spec(self) -> VehicleSpec:
        return VehicleSpec(**self.model_dump())


_POSE = ("road", "lane", "offset", "speed", "heading")


class StartFile(Schema):
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
        description="Id of a traffic trip departing at 0 whose vehicle the agent drives from reset "
        "on (its pose is that vehicle's, so no road, lane, offset, speed or heading).",
    )

    @model_validator(mode="after")
    def _pose_or_take_over(self) -> StartFile:
        if self.take_over is not None:
            problems = [
                (key, f"not allowed with take_over: the agent starts as trip {self.take_over!r}'s vehicle, "
                 "where it is and as fast as it goes")
                for key in _given(self, *_POSE)
            ]  # fmt: skip
        elif self.road is None:
            problems = [("road", "required field missing (a road id, or give take_over instead)")]
        else:
            problems = []
        if problems:
            raise field_errors(self, problems)
        return self

    def to_spec(self) -> StartSpec:
        if self.take_over is not None:
            return StartSpec(take_over=self.take_over)
        return StartSpec(road=self.road, lane=self.lane, offset=self.offset, speed=self.speed, heading=self.heading)


class GoalFile(Schema):
    """Exactly one kind of goal: a position with a radius, a road (and lane, offset), or endless."""

    position: Annotated[list[Number], Field(min_length=2, max_length=2)] | None = Field(
        None, description="[x, y] in metres."
    )
    radius: Positive = Field(3.0, description="m around position; only with a position goal.")
    road: Text | None = None
    lane: Index | None = Field(None, description="Only with a road goal; null: any lane of the road.")
    offset: NonNegative | None = Field(
        None, description="Metres along the goal lane that must be reached; null: entering the road is enough."
    )
    endless: bool | None = Field(None, description="true: drive on with no goal.")

    @property
    def kinds(self) -> list[str]:
        """The goal kinds given (exactly one in a valid goal)."""
        return [k for k in ("position", "road", "endless") if getattr(self, k) is not None]

    @model_validator(mode="after")
    def _one_kind(self) -> GoalFile:
        kinds = self.kinds
        problems: list[tuple[Any, str]] = []
        if len(kinds) != 1:
            got = " and ".join(kinds) if kinds else "none"
            problems.append(((), f"expected exactly one goal kind (position, road or endless: true), got {got}"))
        else:
            for key, needs in (("radius", "position"), ("lane", "road"), ("offset", "road")):
                if getattr(self, key) is not None and _given(self, key) and kinds[0] != needs:
                    problems.append((key, f"only allowed with a {needs} goal, not a {kinds[0]} goal"))
            if self.endless is False:
                problems.append(("endless", "expected true (or give a position or road goal instead), got False"))
        if problems:
            raise field_errors(self, problems)
        return self

    def to_spec(self) -> GoalSpec:
        if self.endless:
            return GoalSpec(endless=True)
        if self.position is not None:
            return GoalSpec(position=(self.position[0], self.position[1]), radius=self.radius)
        return GoalSpec(road=self.road, lane=self.lane, offset=self.offset)


class MissionFile(Schema):
    """Where an agent starts and where it has to go."""

    start: StartFile
    goal: GoalFile
    route_via: list[Text] = Field(default_factory=list, description="Roads the route must pass, in order.")
    on_end: Literal[MISSION_END_ACTIONS] = Field(  # type: ignore[valid-type]
        "remove", description="remove: the vehicle leaves when the mission ends; traffic: traffic drives it on."
    )
    follow: Text | None = Field(
        None, description="Id of the vehicle this agent follows (a traffic trip or another agent)."
    )

    def to_spec(self) -> MissionSpec:
        return MissionSpec(
            start=self.start.to_spec(),
            goal=self.goal.to_spec(),
            route_via=list(self.route_via),
            on_end=self.on_end,
            follow=self.follow,
        )


class AgentFile(Schema):
    """One agent: its action space, vehicle, mission, sensors and (for a social agent) its policy."""

    id: Text | None = Field(None, description="Defaults to agent_<index>.")
    action_space: Literal[ACTION_SPACES] = "relative_target_pose"  # type: ignore[valid-type]
    controller: Literal[CONTROLLERS] = Field(  # type: ignore[valid-type]
        "direct",
        description="direct: the action space's own actions; lane_relative: (acceleration, lane change) "
        "commands turned into them.",
    )
    policy: Annotated[Text, AfterValidator(_locator)] | None = Field(
        None, description="Zoo locator of the policy driving this social agent; null: a learning agent."
    )
    vehicle: VehicleFile = VehicleFile()
    mission: MissionFile | None = Field(None, description="Required unless replay.take_over names the agent.")
    interface: InterfaceFile | None = Field(None, description="Which sensors the agent has; null: the default.")

    @model_validator(mode="after")
    def _controller_fits(self) -> AgentFile:
        if self.controller == "lane_relative" and self.action_space not in LANE_RELATIVE_SPACES:
            raise field_errors(self, [(
                "controller",
                f"lane_relative drives {', '.join(LANE_RELATIVE_SPACES)}; got action_space {self.action_space!r}",
            )])  # fmt: skip
        return self

    def to_spec(self, index: int, replay_vehicle: str | None = None) -> AgentSpec:
        if self.mission is None:  # takes over a recorded vehicle: the env builds its mission
            mission = MissionSpec(start=StartSpec(take_over=replay_vehicle), goal=GoalSpec(endless=True))
        else:
            mission = self.mission.to_spec()
        return AgentSpec(
            id=self.id if self.id is not None else f"agent_{index}",
            mission=mission,
            action_space=self.action_space,
            controller=self.controller,
            vehicle=self.vehicle.to_spec(),
            policy=self.policy,
            interface=None if self.interface is None else self.interface.to_interface(),
        )


# ---------------------------------------------------------------------------- events, reward
class EventsFile(Schema):
    """Which events end an agent's episode, and what counts as not moving."""

    terminate_on: list[Literal[TERMINATION_EVENTS]] = Field(  # type: ignore[valid-type]
        default_factory=lambda: list(DEFAULT_TERMINATE_ON)
    )
    not_moving_seconds: Positive = _EVENTS.not_moving_seconds
    not_moving_distance: NonNegative = Field(
        _EVENTS.not_moving_distance,
        description="A vehicle that moved less than this many metres in not_moving_seconds is not moving.",
    )

    @model_validator(mode="after")
    def _distinct(self) -> EventsFile:
        twice = [
            (("terminate_on", i), f"{name!r} is listed twice")
            for i, name in enumerate(self.terminate_on)
            if name in self.terminate_on[:i]
        ]
        if twice:
            raise field_errors(self, twice)
        return self

    def to_spec(self) -> EventsSpec:
        return EventsSpec(list(self.terminate_on), self.not_moving_seconds, self.not_moving_distance)


class RewardFile(Schema):
    """The built-in reward's terms."""

    progress_weight: NonNegative = Field(_REWARD.progress_weight, description="Per metre of progress along the route.")
    collision_penalty: NonNegative = _REWARD.collision_penalty
    off_road_penalty: NonNegative = _REWARD.off_road_penalty
    goal_bonus: NonNegative = _REWARD.goal_bonus
    step_penalty: NonNegative = Field(
        _REWARD.step_penalty, description="Subtracted every step, to favour reaching the goal sooner."
    )

    def to_spec(self) -> RewardSpec:
        return RewardSpec(**self.model_dump())


# ---------------------------------------------------------------------------- traffic
class VehicleTypeFile(Schema):
    """Driver and vehicle parameters (SUMO vType semantics; see ``VehicleTypeSpec``)."""

    base: Literal[TRAFFIC_VEHICLE_BASES] = Field(  # type: ignore[valid-type]
        _VTYPE.base, description="Dimensions and defaults of this kind of vehicle."
    )
    length: Positive | None = None
    width: Positive | None = None
    height: Positive | None = None
    max_speed: Annotated[float, Field(gt=0, le=MAX_SPEED, allow_inf_nan=False)] = Field(
        _VTYPE.max_speed, description=f"m/s, at most {MAX_SPEED:g}."
    )
    accel: Positive = _VTYPE.accel
    decel: Positive = _VTYPE.decel
    emergency_decel: Positive = _VTYPE.emergency_decel
    tau: Positive = Field(_VTYPE.tau, description="Desired time headway (s).")
    min_gap: NonNegative = Field(_VTYPE.min_gap, description="Standstill gap (m).")
    sigma: Annotated[float, Field(ge=0, le=1)] = Field(_VTYPE.sigma, description="SUMO's driver imperfection.")
    speed_factor: Positive = Field(_VTYPE.speed_factor, description="x the lane speed limit.")
    speed_dev: NonNegative = _VTYPE.speed_dev
    lc_strategic: NonNegative = _VTYPE.lc_strategic
    lc_cooperative: NonNegative = _VTYPE.lc_cooperative
    lc_speed_gain: NonNegative = _VTYPE.lc_speed_gain
    lc_keep_right: NonNegative = _VTYPE.lc_keep_right
    politeness: NonNegative = Field(_VTYPE.politeness, description="MOBIL politeness (built-in engine).")
    lc_threshold: NonNegative = Field(
        _VTYPE.lc_threshold, description="m/s^2 of acceleration advantage a lane change must bring."
    )

    def to_spec(self, name: str) -> VehicleTypeSpec:
        return VehicleTypeSpec(name, **self.model_dump())


def _route_problems(item: Schema) -> list[tuple[Any, str]]:
    """Exactly one way to give the path: ``route`` (>= 1 roads) or origin and destination."""
    ends = [k for k in ("origin", "destination") if getattr(item, k) is not None]
    if getattr(item, "route", None) is not None:
        return [(ends[0], "not allowed with route: give either route or origin and destination")] if ends else []
    if not ends:
        return [((), "expected a route (a list of roads) or origin and destination, got neither")]
    return [
        (key, "required field missing (a road id)") for key in ("origin", "destination") if getattr(item, key) is None
    ]


def _rate_problems(item: Schema) -> list[tuple[Any, str]]:
    given = [k for k in ("rate", "probability") if getattr(item, k) is not None]
    if len(given) == 1:
        return []
    return [((), "expected exactly one of rate (vehicles per hour) or probability (departures per second), "
             f"got {'both' if given else 'neither'}")]  # fmt: skip


def _window_problems(item: Schema) -> list[tuple[Any, str]]:
    begin, end = item.begin, item.end  # type: ignore[attr-defined]
    if end <= begin:
        return [("end", f"expected a time after begin ({begin:g} s), got {end:g}")]
    return []


class _Departure(Schema):
    """What flows and trips share: the path, the vehicle type and how vehicles depart."""

    id: Text
    route: Annotated[list[Text], Field(min_length=1)] | None = Field(
        None, description="Consecutive roads, or some roads the route passes in order."
    )
    origin: Text | None = Field(None, description="First road (with destination, instead of route).")
    destination: Text | None = Field(None, description="Last road (with origin, instead of route).")
    vehicle_type: Text = Field("car", description="Declared in vehicle_types, or car, bus, truck, motorcycle.")
    depart_lane: DepartLane = Field("best", description="best, random, free, first or a lane index.")
    depart_speed: DepartSpeed = Field(
        "desired",
        description="max, desired, random or a speed in m/s (at most the vehicle type's max_speed).",
    )
    depart_pos: NonNegative = Field(0.0, description="Metres along the first road's lane.")


class FlowFile(_Departure):
    """Repeated departures: ``rate`` vehicles per hour or a departure ``probability`` each second."""

    rate: Rate | None = Field(None, description=f"Vehicles per hour (evenly spaced), at most {MAX_FLOW_RATE:,.0f}.")
    probability: Annotated[float, Field(gt=0, le=1)] | None = Field(None, description="Departures per second.")
    begin: Time = Field(0.0, description="s.")
    end: Time = Field(3600.0, description="s, after begin.")

    @model_validator(mode="after")
    def _consistent(self) -> FlowFile:
        problems = _route_problems(self) + _rate_problems(self) + _window_problems(self)
        if problems:
            raise field_errors(self, problems)
        return self

    def to_spec(self) -> FlowSpec:
        return FlowSpec(**self.model_dump())


class TripFile(_Departure):
    """One vehicle departing at ``depart`` seconds; its id in the vehicle table is ``id``."""

    depart: Time = Field(0.0, description="s.")

    @model_validator(mode="after")
    def _consistent(self) -> TripFile:
        problems = _route_problems(self)
        if problems:
            raise field_errors(self, problems)
        return self

    def to_spec(self) -> TripSpec:
        return TripSpec(**self.model_dump())


class PedestrianFile(Schema):
    """People walking from ``origin`` to ``destination`` road (SUMO engine only)."""

    id: Text
    origin: Text
    destination: Text
    rate: Rate | None = Field(None, description=f"People per hour, at most {MAX_FLOW_RATE:,.0f}.")
    probability: Annotated[float, Field(gt=0, le=1)] | None = Field(None, description="Departures per second.")
    begin: Time = 0.0
    end: Time = 3600.0
    speed: Annotated[float, Field(gt=0, le=MAX_WALKING_SPEED, allow_inf_nan=False)] = Field(
        1.3, description=f"Walking speed, m/s, at most {MAX_WALKING_SPEED:g}."
    )

    @model_validator(mode="after")
    def _consistent(self) -> PedestrianFile:
        problems = _rate_problems(self) + _window_problems(self)
        if problems:
            raise field_errors(self, problems)
        return self

    def to_spec(self) -> PedestrianFlowSpec:
        return PedestrianFlowSpec(**self.model_dump())


class TrafficFile(Schema):
    """Who else is on the road, for either traffic engine (see ``smarts.core.spec.traffic``)."""

    engine: Literal[TRAFFIC_ENGINES] = "builtin"  # type: ignore[valid-type]
    density: Literal[DENSITY_LEVELS] = Field(  # type: ignore[valid-type]
        "none", description="Generated flows between all entry and exit roads, on top of the listed flows."
    )
    vehicle_types: dict[Text, VehicleTypeFile] = Field(default_factory=dict, description="type name -> parameters")
    flows: list[FlowFile] = Field(default_factory=list)
    trips: list[TripFile] = Field(default_factory=list)
    pedestrians: list[PedestrianFile] = Field(default_factory=list, description="SUMO only.")

    @model_validator(mode="after")
    def _consistent(self) -> TrafficFile:
        problems: list[tuple[Any, str]] = []
        for key, items in (("flows", self.flows), ("trips", self.trips)):
            for i, item in enumerate(items):
                name = item.vehicle_type
                if name not in self.vehicle_types and name not in DEFAULT_VEHICLE_TYPES:
                    problems.append(((key, i, "vehicle_type"), (
                        f"unknown vehicle type {name!r}; declared in traffic.vehicle_types: "
                        f"{', '.join(self.vehicle_types) or 'none'}; always available: {', '.join(DEFAULT_VEHICLE_TYPES)}"
                    )))  # fmt: skip
                    continue
                vtype = self.vehicle_types.get(name) or DEFAULT_VEHICLE_TYPES[name]
                speed = item.depart_speed
                if not isinstance(speed, str) and speed > vtype.max_speed:
                    problems.append(((key, i, "depart_speed"), (
                        f"expected at most vehicle type {name!r}'s max_speed ({vtype.max_speed:g} m/s), got {speed:g}"
                    )))  # fmt: skip
        departures = [("flows", i, f.id) for i, f in enumerate(self.flows)]
        departures += [("trips", i, t.id) for i, t in enumerate(self.trips)]
        problems += _duplicates(departures, "flows and trips")
        problems += _duplicates([("pedestrians", i, p.id) for i, p in enumerate(self.pedestrians)], "pedestrian flows")
        if self.pedestrians and self.engine != "sumo":
            problems.append((
                "pedestrians",
                f"pedestrians need engine: sumo (the {self.engine} engine has none), got engine {self.engine!r}",
            ))  # fmt: skip
        if problems:
            raise field_errors(self, problems)
        return self

    def to_spec(self) -> TrafficSpec:
        return TrafficSpec(
            engine=self.engine,
            density=self.density,
            vehicle_types={name: vtype.to_spec(name) for name, vtype in self.vehicle_types.items()},
            flows=[f.to_spec() for f in self.flows],
            trips=[t.to_spec() for t in self.trips],
            pedestrians=[p.to_spec() for p in self.pedestrians],
        )


def _duplicates(ids: list[tuple[str, int, str]], among: str) -> list[tuple[Any, str]]:
    seen: dict[str, str] = {}
    problems: list[tuple[Any, str]] = []
    for key, i, item_id in ids:
        if item_id in seen:
            problems.append(((key, i, "id"), f"duplicate id {item_id!r} among {among} (also {seen[item_id]})"))
        else:
            seen[item_id] = f"traffic.{key}[{i}].id"
    return problems


# ---------------------------------------------------------------------------- the file
class ScenarioFile(Schema):
    """A scenario file's top level."""

    name: Text = Field(description="Defaults to the file's name when read from a file.")
    map: Annotated[Text, AfterValidator(_map_name)] = Field(
        description="builtin:<name> or a .net.xml/.xodr path relative to the scenario file's folder."
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
    agents: Annotated[list[AgentFile], Field(min_length=1)]
    events: EventsFile = EventsFile()
    reward: RewardFile = RewardFile()
    traffic: TrafficFile | None = Field(None, description="null: agents only.")
    comms: CommsFile | None = Field(None, description="V2V messaging; null: off.")
    replay: ReplayFile | None = Field(None, description="Recorded traffic replayed from a dataset; null: none.")

    @property
    def agent_ids(self) -> list[str]:
        return [a.id if a.id is not None else f"agent_{i}" for i, a in enumerate(self.agents)]

    @model_validator(mode="after")
    def _consistent(self) -> ScenarioFile:
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

    def _agents_and_replay(self, ids: list[str]) -> list[tuple[Any, str]]:
        """Agents taking over recorded vehicles have no mission of their own; the others need one."""
        taken = {} if self.replay is None else self.replay.take_over
        problems: list[tuple[Any, str]] = []
        for i, agent in enumerate(self.agents):
            if ids[i] in taken and agent.mission is not None:
                problems.append((("agents", i, "mission"), f"not allowed: replay.take_over gives agent {ids[i]!r} "
                                 f"recorded vehicle {taken[ids[i]]!r}, whose track sets its start and goal"))  # fmt: skip
            elif ids[i] not in taken and agent.mission is None:
                problems.append(
                    (("agents", i, "mission"), "required field missing (or name the agent in replay.take_over)")
                )
        for agent_id in taken:
            if agent_id not in ids:
                problems.append((("replay", "take_over", agent_id), f"unknown agent {agent_id!r}{_did_you_mean(agent_id, ids)}; "
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
            mission = agent.mission
            if mission is None:  # takes over a recorded vehicle (checked with the replay)
                continue
            trip_id = mission.start.take_over
            where = ("agents", i, "mission", "start", "take_over")
            if trip_id is None:
                pass
            elif traffic is None:
                problems.append((where, f"no trip {trip_id!r} to take over: the scenario has no traffic section"))
            elif trip_id not in trips:
                problems.append((where, f"unknown trip {trip_id!r}{_did_you_mean(trip_id, trips)}; "
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
            if agent.mission is None:
                continue
            lead = agent.mission.follow
            where = ("agents", i, "mission", "follow")
            if lead is None:
                continue
            if lead == ids[i]:
                problems.append((where, "an agent cannot follow itself"))
            elif lead not in trips and lead not in agent_index:
                known = [*trips, *agent_index]
                problems.append((where, f"no vehicle {lead!r} to follow{_did_you_mean(lead, known)}; "
                                 f"traffic.trips and agents: {', '.join(known) or 'none'}"))  # fmt: skip
        for j, trip in enumerate(traffic.trips if traffic is not None else []):
            if trip.id in agent_index:
                problems.append((("traffic", "trips", j, "id"), f"{trip.id!r} is also the id of "
                                 f"agents[{agent_index[trip.id]}]; vehicle ids must be unique"))  # fmt: skip
        return problems

    def to_spec(self, spec_class: type[ScenarioSpec], source: str, base_dir: Path | None) -> ScenarioSpec:
        """The validated file as the simulator's dataclasses."""
        return spec_class(
            name=self.name,
            map=self.map,
            agents=[
                agent.to_spec(i, None if self.replay is None else self.replay.take_over.get(agent_id))
                for i, (agent, agent_id) in enumerate(zip(self.agents, self.agent_ids))
            ],
            step_length=self.step_length,
            episode_steps=self.episode_steps,
            seed=self.seed,
            vehicle_capacity=self.vehicle_capacity,
            events=self.events.to_spec(),
            reward=self.reward.to_spec(),
            traffic=None if self.traffic is None else self.traffic.to_spec(),
            comms=None if self.comms is None else self.comms.to_config(),
            replay=None if self.replay is None else self.replay.to_spec(),
            source=source,
            base_dir=base_dir,
        )


def _did_you_mean(name: str, known: Any) -> str:
    hint = difflib.get_close_matches(name, list(known), n=1)
    return f" (did you mean {hint[0]!r}?)" if hint else ""
