"""The scenario spec: what a YAML scenario file may say, as dataclasses, strictly validated.

Validation happens once, when the file is read, so the simulator can trust every field. Each error
names the file and the dotted field path (``agents[1].mission.goal.radius``) and says what was
expected, because a scenario author should never have to guess which line is wrong.
"""

from __future__ import annotations

import difflib
import math
import os
from collections.abc import Mapping
from dataclasses import dataclass, field, fields
from pathlib import Path
from typing import TYPE_CHECKING, Any

import yaml

from smarts.core.vehicle_table import VEHICLE_DIMENSIONS, VehicleType
from smarts.scenario.builtin_maps import BUILTIN_MAPS, builtin_map_path
from smarts.core.errors import ScenarioError
from smarts.scenario.traffic import (
    DEFAULT_VEHICLE_TYPES,
    DENSITY_LEVELS,
    DEPART_LANES,
    DEPART_SPEEDS,
    TRAFFIC_ENGINES,
    FlowSpec,
    PedestrianFlowSpec,
    TrafficSpec,
    TripSpec,
    VehicleTypeSpec,
)
from smarts.sensors.interface import (
    AgentInterface,
    InterfaceError,
    interface_from_dict,
    interface_to_dict,
)

if TYPE_CHECKING:  # the reader imports it only for scenarios with a comms section
    from smarts.comms.config import CommsConfig

BUILTIN_PREFIX = "builtin:"
MAP_FILE_SUFFIXES = (".net.xml", ".xodr")

ACTION_SPACES = ("relative_target_pose", "target_pose", "continuous", "lane")
CONTROLLERS = ("direct", "lane_relative")
"""How an agent's actions reach its action space: ``direct`` (the space's own actions) or
``lane_relative`` (acceleration and lane-change commands turned into that space's actions by
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
TRAFFIC_VEHICLE_BASES = ("passenger", "bus", "truck", "motorcycle")
ZOO_PREFIX = "zoo:"


@dataclass(frozen=True)
class VehicleDimensions:
    length: float
    width: float
    height: float
    mass: float


VEHICLE_TYPES: dict[str, VehicleDimensions] = {
    t.name.lower(): VehicleDimensions(*VEHICLE_DIMENSIONS[t]) for t in VehicleType if t is not VehicleType.PEDESTRIAN
}
"""Typical dimensions (m) and mass (kg) per vehicle type; a scenario may override each one."""


# ---------------------------------------------------------------------------- dataclasses
@dataclass
class VehicleSpec:
    type: str = "passenger"
    length: float | None = None
    width: float | None = None
    height: float | None = None
    mass: float | None = None

    def dimensions(self) -> VehicleDimensions:
        """The type's defaults with this spec's overrides applied."""
        base = VEHICLE_TYPES[self.type]
        return VehicleDimensions(
            length=base.length if self.length is None else self.length,
            width=base.width if self.width is None else self.width,
            height=base.height if self.height is None else self.height,
            mass=base.mass if self.mass is None else self.mass,
        )


@dataclass
class StartSpec:
    road: str | None = None
    """None only when ``take_over`` names the vehicle to start in."""
    lane: int = 0
    offset: float = 0.0
    """Metres along the lane from its start."""
    speed: float = 0.0
    heading: float | None = None
    """Radians; None means along the lane."""
    take_over: str | None = None
    """Id of a traffic trip departing at 0 whose vehicle the agent drives from reset on; the start
    pose is then that vehicle's, so road, lane, offset, speed and heading are not given."""


@dataclass
class GoalSpec:
    """Exactly one kind of goal: a position with a radius, a road (and lane), or endless driving."""

    position: tuple[float, float] | None = None
    radius: float = 3.0
    road: str | None = None
    lane: int | None = None
    """None: any lane of the road."""
    offset: float | None = None
    """Metres along the goal lane that must be reached; None: entering the road is enough."""
    endless: bool = False

    @property
    def kind(self) -> str:
        if self.endless:
            return "endless"
        return "position" if self.position is not None else "road"


@dataclass
class MissionSpec:
    start: StartSpec
    goal: GoalSpec
    route_via: list[str] = field(default_factory=list)
    on_end: str = "remove"
    """``remove``: the vehicle leaves when the mission ends; ``traffic``: traffic drives it on."""
    follow: str | None = None
    """Id of the vehicle this agent follows (a traffic trip or another agent): the lead of the
    following task, seen in the ``lead`` observation block and scored by SFD. None: no lead."""


@dataclass
class AgentSpec:
    id: str
    mission: MissionSpec
    action_space: str = "relative_target_pose"
    controller: str = "direct"
    """``direct``: actions are the action space's own; ``lane_relative``: (acceleration, lane
    change) commands that ``smarts.dynamics.lane_relative`` turns into the action space's actions."""
    vehicle: VehicleSpec = field(default_factory=VehicleSpec)
    policy: str | None = None
    """Zoo locator (``zoo:keep-lane`` or ``keep-lane``) of the policy that drives this agent inside
    the simulator: a social agent, not controlled by the learner. None: a learning agent."""
    interface: AgentInterface | None = None
    """Which sensors the agent has (``smarts.sensors.interface``); None: the default interface."""

    @property
    def is_social(self) -> bool:
        return self.policy is not None


@dataclass
class EventsSpec:
    terminate_on: list[str] = field(default_factory=lambda: list(DEFAULT_TERMINATE_ON))
    not_moving_seconds: float = 60.0
    not_moving_distance: float = 1.0
    """A vehicle that moved less than this many metres in ``not_moving_seconds`` is not moving."""


@dataclass
class RewardSpec:
    progress_weight: float = 1.0
    """Reward per metre of progress along the route."""
    collision_penalty: float = 10.0
    off_road_penalty: float = 10.0
    goal_bonus: float = 10.0
    step_penalty: float = 0.0
    """Subtracted every step, to favour reaching the goal sooner."""


@dataclass
class ScenarioSpec:
    name: str
    map: str
    """``builtin:<name>`` or a .net.xml/.xodr path relative to the scenario file's folder."""
    agents: list[AgentSpec]
    step_length: float = 0.1
    episode_steps: int = 1000
    seed: int = 42
    vehicle_capacity: int = 256
    events: EventsSpec = field(default_factory=EventsSpec)
    reward: RewardSpec = field(default_factory=RewardSpec)
    traffic: TrafficSpec | None = None
    """Flows, trips, vehicle types and pedestrians for a traffic engine; None: agents only."""
    comms: CommsConfig | None = None
    """V2V messaging between agents and connected traffic (``smarts.comms``); None: comms off, the
    action and observation spaces have no message parts."""
    source: str = field(default="<dict>", compare=False, repr=False)
    """Where the spec was read from; prefixes every error message."""
    base_dir: Path | None = field(default=None, compare=False, repr=False)
    """Folder that relative map paths are resolved against (the scenario file's folder)."""

    # ------------------------------------------------------------------ reading
    @classmethod
    def from_yaml(cls, path: str | os.PathLike) -> ScenarioSpec:
        path = Path(path)
        source = str(path)
        try:
            text = path.read_text(encoding="utf-8")
        except OSError as exc:
            raise ScenarioError(
                f"{source}: cannot read scenario file: {exc.strerror or exc}"
            ) from None
        try:
            data = yaml.safe_load(text)
        except yaml.YAMLError as exc:
            mark = getattr(exc, "problem_mark", None)
            where = f" at line {mark.line + 1}, column {mark.column + 1}" if mark else ""
            problem = getattr(exc, "problem", None) or str(exc)
            raise ScenarioError(f"{source}: invalid YAML{where}: {problem}") from None
        if isinstance(data, dict) and "name" not in data:
            data = {"name": path.name.split(".")[0], **data}
        return cls.from_dict(data, source=source, base_dir=path.parent)

    @classmethod
    def from_dict(
        cls,
        data: Mapping[str, Any],
        source: str = "<dict>",
        base_dir: str | os.PathLike | None = None,
    ) -> ScenarioSpec:
        """Validate a plain mapping (as loaded from YAML) into a spec.

        ``source`` prefixes error messages; a relative map path is resolved against ``base_dir``
        (the current directory when None).
        """
        return _Reader(source, None if base_dir is None else Path(base_dir)).scenario(data)

    # ------------------------------------------------------------------ writing
    def to_dict(self) -> dict[str, Any]:
        """Plain data (lists, dicts, scalars) that ``from_dict`` turns back into an equal spec."""
        return {
            "name": self.name,
            "map": self.map,
            "step_length": self.step_length,
            "episode_steps": self.episode_steps,
            "seed": self.seed,
            "vehicle_capacity": self.vehicle_capacity,
            "agents": [_agent_dict(a) for a in self.agents],
            "events": {
                "terminate_on": list(self.events.terminate_on),
                "not_moving_seconds": self.events.not_moving_seconds,
                "not_moving_distance": self.events.not_moving_distance,
            },
            "reward": {
                "progress_weight": self.reward.progress_weight,
                "collision_penalty": self.reward.collision_penalty,
                "off_road_penalty": self.reward.off_road_penalty,
                "goal_bonus": self.reward.goal_bonus,
                "step_penalty": self.reward.step_penalty,
            },
            "traffic": None if self.traffic is None else _traffic_dict(self.traffic),
            "comms": None if self.comms is None else _comms_dict(self.comms),
        }

    def to_yaml(self) -> str:
        return yaml.dump(self.to_dict(), Dumper=_SpecDumper, sort_keys=False)

    # ------------------------------------------------------------------ map
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

    def map_path(self, cache_dir: str | os.PathLike | None = None) -> Path:
        """The map file to load: a built-in map is compiled (and cached) by netconvert first."""
        if self.builtin_map is not None:
            return builtin_map_path(self.builtin_map, cache_dir)
        return _resolve_map_file(self.map, self.base_dir)

    def check_map(self, road_map: Any) -> None:
        """Check every mission's and every traffic entry's roads, lanes and offsets against the map.

        ``road_map`` needs ``road_index_of``, ``road_lanes(road)`` and ``lane_length`` (and uses
        ``lane_internal`` and ``bounds`` when present), as on :class:`smarts.maps.road_map.RoadMap`.
        """
        checker = _MapChecker(self.source, road_map)
        for i, agent in enumerate(self.agents):
            where = f"agents[{i}].mission"
            start = agent.mission.start
            if start.take_over is None:  # a taken-over vehicle starts where its trip departs
                checker.road_lane(f"{where}.start", start.road, start.lane, start.offset)
            goal = agent.mission.goal
            if goal.kind == "road":
                checker.road_lane(f"{where}.goal", goal.road, goal.lane, goal.offset)
            elif goal.kind == "position":
                checker.position(f"{where}.goal.position", goal.position, goal.radius)
            for j, road in enumerate(agent.mission.route_via):
                checker.road(f"{where}.route_via[{j}]", road)
        if self.traffic is not None:
            checker.traffic(self.traffic)


def _agent_dict(agent: AgentSpec) -> dict[str, Any]:
    vehicle: dict[str, Any] = {"type": agent.vehicle.type}
    for key in ("length", "width", "height", "mass"):
        if getattr(agent.vehicle, key) is not None:
            vehicle[key] = getattr(agent.vehicle, key)
    start = agent.mission.start
    start_d: dict[str, Any]
    if start.take_over is not None:
        start_d = {"take_over": start.take_over}
    else:
        start_d = {
            "road": start.road,
            "lane": start.lane,
            "offset": start.offset,
            "speed": start.speed,
        }
        if start.heading is not None:
            start_d["heading"] = start.heading
    goal = agent.mission.goal
    goal_d: dict[str, Any]
    if goal.kind == "endless":
        goal_d = {"endless": True}
    elif goal.kind == "position":
        goal_d = {"position": list(goal.position), "radius": goal.radius}
    else:
        goal_d = {"road": goal.road}
        if goal.lane is not None:
            goal_d["lane"] = goal.lane
        if goal.offset is not None:
            goal_d["offset"] = goal.offset
    mission: dict[str, Any] = {"start": start_d, "goal": goal_d}
    if agent.mission.route_via:
        mission["route_via"] = list(agent.mission.route_via)
    if agent.mission.on_end != "remove":
        mission["on_end"] = agent.mission.on_end
    if agent.mission.follow is not None:
        mission["follow"] = agent.mission.follow
    agent_d: dict[str, Any] = {"id": agent.id, "action_space": agent.action_space}
    if agent.controller != "direct":
        agent_d["controller"] = agent.controller
    if agent.policy is not None:
        agent_d["policy"] = agent.policy
    agent_d["vehicle"] = vehicle
    agent_d["mission"] = mission
    if agent.interface is not None:
        agent_d["interface"] = interface_to_dict(agent.interface)
    return agent_d


def _without_none(item: Any, *, drop: tuple[str, ...] = ()) -> dict[str, Any]:
    """A traffic dataclass as a mapping, leaving out unset (None) fields and those in ``drop``."""
    out = {}
    for f in fields(item):
        value = getattr(item, f.name)
        if value is None or f.name in drop:
            continue
        out[f.name] = list(value) if isinstance(value, list) else value
    return out


def _traffic_dict(traffic: TrafficSpec) -> dict[str, Any]:
    return {
        "engine": traffic.engine,
        "density": traffic.density,
        "vehicle_types": {
            name: _without_none(vtype, drop=("id",))
            for name, vtype in traffic.vehicle_types.items()
        },
        "flows": [_without_none(flow) for flow in traffic.flows],
        "trips": [_without_none(trip) for trip in traffic.trips],
        "pedestrians": [_without_none(ped) for ped in traffic.pedestrians],
    }


def _comms_dict(comms: CommsConfig) -> dict[str, Any]:
    """Every comms field (a default written out reads back the same)."""
    out = {f.name: getattr(comms, f.name) for f in fields(comms)}
    out["agent_channels"] = dict(comms.agent_channels)
    return out


class _SpecDumper(yaml.SafeDumper):
    """Writes short lists of scalars (positions, event names) inline, everything else as blocks."""

    def increase_indent(self, flow: bool = False, indentless: bool = False) -> None:
        # Indent list items under their key, as people write them by hand.
        return super().increase_indent(flow, False)


def _represent_list(dumper: yaml.SafeDumper, data: list) -> yaml.Node:
    flow = all(not isinstance(v, (dict, list)) for v in data) and len(data) <= 8
    return dumper.represent_sequence("tag:yaml.org,2002:seq", data, flow_style=flow)


_SpecDumper.add_representer(list, _represent_list)


def _resolve_map_file(map_value: str, base_dir: Path | None) -> Path:
    path = Path(map_value).expanduser()
    if not path.is_absolute():
        path = (base_dir if base_dir is not None else Path.cwd()) / path
    return path


# ---------------------------------------------------------------------------- validation
_REQUIRED = object()


def _describe(value: Any) -> str:
    if isinstance(value, (dict, list)):
        text = repr(value)
        if len(text) <= 60:
            return text
        return f"a {'mapping' if isinstance(value, dict) else 'list'} of {len(value)} items"
    if value is None:
        return "nothing (null)"
    return repr(value)


def _join(path: str, key: str) -> str:
    return f"{path}.{key}" if path else key


class _Reader:
    """Turns loaded YAML data into spec dataclasses, raising on the first invalid field."""

    def __init__(self, source: str, base_dir: Path | None) -> None:
        self.source = source
        self.base_dir = base_dir

    def error(self, path: str, message: str) -> ScenarioError:
        return ScenarioError(
            f"{self.source}: {path}: {message}" if path else f"{self.source}: {message}"
        )

    # ---------------------------------------------------------------- primitives
    def mapping(self, value: Any, path: str, allowed: tuple[str, ...]) -> dict[str, Any]:
        if not isinstance(value, dict):
            what = "a mapping of scenario fields" if not path else "a mapping"
            raise self.error(path, f"expected {what}, got {_describe(value)}")
        for key in value:
            if not isinstance(key, str) or key not in allowed:
                hint = difflib.get_close_matches(str(key), allowed, n=1)
                suggestion = f" (did you mean {hint[0]!r}?)" if hint else ""
                raise self.error(
                    _join(path, str(key)),
                    f"unknown field{suggestion}; allowed fields: {', '.join(allowed)}",
                )
        return value

    def string(self, d: dict, key: str, path: str, default: Any = _REQUIRED) -> Any:
        p = _join(path, key)
        if key not in d:
            if default is _REQUIRED:
                raise self.error(p, "missing required field (a string)")
            return default
        value = d[key]
        if not isinstance(value, str) or not value.strip():
            raise self.error(p, f"expected a non-empty string, got {_describe(value)}")
        return value

    def number(
        self,
        d: dict,
        key: str,
        path: str,
        default: Any = _REQUIRED,
        *,
        positive: bool = False,
        non_negative: bool = False,
        maximum: float | None = None,
        optional: bool = False,
    ) -> Any:
        p = _join(path, key)
        if key not in d:
            if default is _REQUIRED:
                raise self.error(p, "missing required field (a number)")
            return default
        value = d[key]
        if optional and value is None:
            return None
        return self.check_number(
            value, p, positive=positive, non_negative=non_negative, maximum=maximum
        )

    def check_number(
        self,
        value: Any,
        path: str,
        *,
        positive: bool = False,
        non_negative: bool = False,
        maximum: float | None = None,
    ) -> float:
        kind = (
            "a positive number"
            if positive
            else "a non-negative number"
            if non_negative
            else "a number"
        )
        if maximum is not None:
            kind += f" <= {maximum:g}"
        if (
            isinstance(value, bool)
            or not isinstance(value, (int, float))
            or not math.isfinite(value)
        ):
            raise self.error(path, f"expected {kind}, got {_describe(value)}")
        if (
            (positive and value <= 0)
            or (non_negative and value < 0)
            or (maximum is not None and value > maximum)
        ):
            raise self.error(path, f"expected {kind}, got {value:g}")
        return float(value)

    def integer(
        self,
        d: dict,
        key: str,
        path: str,
        default: Any = _REQUIRED,
        *,
        minimum: int | None = None,
        optional: bool = False,
    ) -> Any:
        p = _join(path, key)
        if key not in d:
            if default is _REQUIRED:
                raise self.error(p, "missing required field (an integer)")
            return default
        value = d[key]
        if optional and value is None:
            return None
        kind = "an integer" if minimum is None else f"an integer >= {minimum}"
        if isinstance(value, bool) or not isinstance(value, int):
            raise self.error(p, f"expected {kind}, got {_describe(value)}")
        if minimum is not None and value < minimum:
            raise self.error(p, f"expected {kind}, got {value}")
        return value

    def choice(self, d: dict, key: str, path: str, choices: tuple[str, ...], default: str) -> str:
        value = d.get(key, default)
        if value not in choices or not isinstance(value, str):
            raise self.error(
                _join(path, key), f"expected one of {', '.join(choices)}; got {_describe(value)}"
            )
        return value

    def string_list(self, d: dict, key: str, path: str, default: list[str]) -> list[str]:
        p = _join(path, key)
        value = d.get(key, default)
        if not isinstance(value, list):
            raise self.error(p, f"expected a list of strings, got {_describe(value)}")
        for i, item in enumerate(value):
            if not isinstance(item, str) or not item.strip():
                raise self.error(f"{p}[{i}]", f"expected a non-empty string, got {_describe(item)}")
        return list(value)

    # ---------------------------------------------------------------- spec parts
    def scenario(self, data: Any) -> ScenarioSpec:
        allowed = (
            "name", "map", "step_length", "episode_steps", "seed", "vehicle_capacity",
            "agents", "events", "reward", "traffic", "comms",
        )  # fmt: skip
        d = self.mapping(data, "", allowed)
        name = self.string(d, "name", "")
        map_value = self.map_field(d)
        step_length = self.number(d, "step_length", "", 0.1, positive=True, maximum=1.0)
        episode_steps = self.integer(d, "episode_steps", "", 1000, minimum=1)
        seed = self.integer(d, "seed", "", 42, minimum=0)
        capacity = self.integer(d, "vehicle_capacity", "", 256, minimum=1)
        agents = self.agents(d.get("agents", _REQUIRED))
        if capacity < len(agents):
            raise self.error(
                "vehicle_capacity",
                f"expected at least the number of agents ({len(agents)}), got {capacity}",
            )
        events = self.events(d.get("events", {}))
        reward = self.reward(d.get("reward", {}))
        traffic = None if d.get("traffic") is None else self.traffic(d["traffic"])
        self.agents_and_traffic(agents, traffic)
        comms = None if d.get("comms") is None else self.comms(d["comms"], agents)
        return ScenarioSpec(
            name=name,
            map=map_value,
            agents=agents,
            step_length=step_length,
            episode_steps=episode_steps,
            seed=seed,
            vehicle_capacity=capacity,
            events=events,
            reward=reward,
            traffic=traffic,
            comms=comms,
            source=self.source,
            base_dir=self.base_dir,
        )

    def map_field(self, d: dict) -> str:
        value = self.string(d, "map", "")
        if value.startswith(BUILTIN_PREFIX):
            name = value[len(BUILTIN_PREFIX) :]
            if name not in BUILTIN_MAPS:
                hint = difflib.get_close_matches(name, BUILTIN_MAPS, n=1)
                suggestion = f" (did you mean {hint[0]!r}?)" if hint else ""
                raise self.error(
                    "map",
                    f"unknown built-in map {name!r}{suggestion}; "
                    f"known: {', '.join(sorted(BUILTIN_MAPS))}",
                )
            return value
        if not value.endswith(MAP_FILE_SUFFIXES):
            raise self.error(
                "map",
                f"expected 'builtin:<name>' or a path ending in {' or '.join(MAP_FILE_SUFFIXES)}, "
                f"got {value!r}",
            )
        path = _resolve_map_file(value, self.base_dir)
        if not path.is_file():
            raise self.error("map", f"map file {str(path)!r} does not exist")
        return value

    def agents(self, value: Any) -> list[AgentSpec]:
        if value is _REQUIRED:
            raise self.error("agents", "missing required field (a list of at least one agent)")
        if not isinstance(value, list) or not value:
            raise self.error(
                "agents", f"expected a list of at least one agent, got {_describe(value)}"
            )
        agents = [self.agent(item, f"agents[{i}]", i) for i, item in enumerate(value)]
        seen: dict[str, int] = {}
        for i, agent in enumerate(agents):
            if agent.id in seen:
                raise self.error(
                    f"agents[{i}].id",
                    f"duplicate agent id {agent.id!r} (also agents[{seen[agent.id]}])",
                )
            seen[agent.id] = i
        return agents

    def agent(self, value: Any, path: str, index: int) -> AgentSpec:
        d = self.mapping(
            value, path, ("id", "action_space", "controller", "policy", "vehicle", "mission", "interface")
        )
        agent_id = self.string(d, "id", path, f"agent_{index}")
        action_space = self.choice(d, "action_space", path, ACTION_SPACES, "relative_target_pose")
        controller = self.choice(d, "controller", path, CONTROLLERS, "direct")
        if controller == "lane_relative" and action_space not in LANE_RELATIVE_SPACES:
            raise self.error(
                _join(path, "controller"),
                f"lane_relative drives {', '.join(LANE_RELATIVE_SPACES)}; got action_space {action_space!r}",
            )
        policy = self.policy(d, path)
        vehicle = self.vehicle(d.get("vehicle", {}), _join(path, "vehicle"))
        if "mission" not in d:
            raise self.error(_join(path, "mission"), "missing required field (start and goal)")
        mission = self.mission(d["mission"], _join(path, "mission"))
        return AgentSpec(
            id=agent_id,
            mission=mission,
            action_space=action_space,
            controller=controller,
            vehicle=vehicle,
            policy=policy,
            interface=self.interface(d, path),
        )

    def interface(self, d: dict, path: str) -> AgentInterface | None:
        """The agent's sensors; validated by ``smarts.sensors.interface`` with this field's path."""
        if d.get("interface") is None:
            return None
        try:
            return interface_from_dict(d["interface"], _join(path, "interface"))
        except InterfaceError as err:
            raise self.error(err.path, err.problem) from None

    def policy(self, d: dict, path: str) -> str | None:
        """A zoo locator; only its form is checked here, the zoo resolves it when the env starts."""
        if d.get("policy") is None:
            return None
        locator = self.string(d, "policy", path)
        name = locator.removeprefix(ZOO_PREFIX)
        if not name or any(c.isspace() for c in locator):
            raise self.error(
                _join(path, "policy"),
                f"expected a zoo locator such as 'zoo:keep-lane' or 'keep-lane', got {locator!r}",
            )
        return locator

    def vehicle(self, value: Any, path: str) -> VehicleSpec:
        d = self.mapping(value, path, ("type", "length", "width", "height", "mass"))
        return VehicleSpec(
            type=self.choice(d, "type", path, tuple(VEHICLE_TYPES), "passenger"),
            **{
                key: self.number(d, key, path, None, positive=True, optional=True)
                for key in ("length", "width", "height", "mass")
            },
        )

    def mission(self, value: Any, path: str) -> MissionSpec:
        d = self.mapping(value, path, ("start", "goal", "route_via", "on_end", "follow"))
        if "start" not in d:
            raise self.error(
                _join(path, "start"),
                "missing required field (road, lane, offset, ... or take_over: <trip id>)",
            )
        start = self.start(d["start"], _join(path, "start"))
        if "goal" not in d:
            raise self.error(
                _join(path, "goal"), "missing required field (position, road or endless: true)"
            )
        goal = self.goal(d["goal"], _join(path, "goal"))
        route_via = self.string_list(d, "route_via", path, [])
        on_end = self.choice(d, "on_end", path, MISSION_END_ACTIONS, "remove")
        follow = self.string(d, "follow", path, None)
        return MissionSpec(start=start, goal=goal, route_via=route_via, on_end=on_end, follow=follow)

    def start(self, value: Any, path: str) -> StartSpec:
        pose = ("road", "lane", "offset", "speed", "heading")
        d = self.mapping(value, path, (*pose, "take_over"))
        if d.get("take_over") is not None:
            trip = self.string(d, "take_over", path)
            for key in pose:
                if key in d:
                    raise self.error(
                        _join(path, key),
                        f"not allowed with take_over: the agent starts as trip {trip!r}'s vehicle, "
                        "where it is and as fast as it goes",
                    )
            return StartSpec(take_over=trip)
        if "road" not in d:
            raise self.error(
                _join(path, "road"), "missing required field (a road id, or give take_over instead)"
            )
        return StartSpec(
            road=self.string(d, "road", path),
            lane=self.integer(d, "lane", path, 0, minimum=0),
            offset=self.number(d, "offset", path, 0.0, non_negative=True),
            speed=self.number(d, "speed", path, 0.0, non_negative=True),
            heading=self.number(d, "heading", path, None, optional=True),
        )

    def goal(self, value: Any, path: str) -> GoalSpec:
        d = self.mapping(value, path, ("position", "radius", "road", "lane", "offset", "endless"))
        kinds = [k for k in ("position", "road", "endless") if k in d]
        if len(kinds) != 1:
            got = " and ".join(kinds) if kinds else "none"
            raise self.error(
                path, f"expected exactly one goal kind (position, road or endless: true), got {got}"
            )
        kind = kinds[0]
        for key, needs in (("radius", "position"), ("lane", "road"), ("offset", "road")):
            if key in d and kind != needs:
                raise self.error(
                    _join(path, key), f"only allowed with a {needs} goal, not a {kind} goal"
                )
        if kind == "endless":
            if d["endless"] is not True:
                raise self.error(
                    _join(path, "endless"),
                    "expected true (or give a position or road goal instead), "
                    f"got {_describe(d['endless'])}",
                )
            return GoalSpec(endless=True)
        if kind == "position":
            p = _join(path, "position")
            pos = d["position"]
            if not isinstance(pos, list) or len(pos) != 2:
                raise self.error(p, f"expected [x, y] in metres, got {_describe(pos)}")
            xy = tuple(self.check_number(v, f"{p}[{i}]") for i, v in enumerate(pos))
            radius = self.number(d, "radius", path, 3.0, positive=True)
            return GoalSpec(position=xy, radius=radius)
        return GoalSpec(
            road=self.string(d, "road", path),
            lane=self.integer(d, "lane", path, None, minimum=0, optional=True),
            offset=self.number(d, "offset", path, None, non_negative=True, optional=True),
        )

    # ---------------------------------------------------------------- traffic
    def traffic(self, value: Any) -> TrafficSpec:
        path = "traffic"
        allowed = ("engine", "density", "vehicle_types", "flows", "trips", "pedestrians")
        d = self.mapping(value, path, allowed)
        engine = self.choice(d, "engine", path, TRAFFIC_ENGINES, "builtin")
        density = self.choice(d, "density", path, DENSITY_LEVELS, "none")
        vehicle_types = self.vehicle_types(d.get("vehicle_types", {}), "traffic.vehicle_types")
        flows = [
            self.flow(item, f"{path}.flows[{i}]", vehicle_types)
            for i, item in enumerate(self.item_list(d, "flows", path))
        ]
        trips = [
            self.trip(item, f"{path}.trips[{i}]", vehicle_types)
            for i, item in enumerate(self.item_list(d, "trips", path))
        ]
        self.unique_ids(
            [(f"{path}.flows[{i}].id", f.id) for i, f in enumerate(flows)]
            + [(f"{path}.trips[{i}].id", t.id) for i, t in enumerate(trips)],
            "flows and trips",
        )
        pedestrians = [
            self.pedestrian(item, f"{path}.pedestrians[{i}]")
            for i, item in enumerate(self.item_list(d, "pedestrians", path))
        ]
        self.unique_ids(
            [(f"{path}.pedestrians[{i}].id", p.id) for i, p in enumerate(pedestrians)],
            "pedestrian flows",
        )
        if pedestrians and engine != "sumo":
            raise self.error(
                f"{path}.pedestrians",
                f"pedestrians need engine: sumo (the {engine} engine has none), "
                f"got engine {engine!r}",
            )
        return TrafficSpec(
            engine=engine,
            density=density,
            vehicle_types=vehicle_types,
            flows=flows,
            trips=trips,
            pedestrians=pedestrians,
        )

    def item_list(self, d: dict, key: str, path: str) -> list:
        value = d.get(key, [])
        if not isinstance(value, list):
            raise self.error(_join(path, key), f"expected a list, got {_describe(value)}")
        return value

    def unique_ids(self, ids: list[tuple[str, str]], among: str) -> None:
        seen: dict[str, str] = {}
        for path, item_id in ids:
            if item_id in seen:
                raise self.error(
                    path, f"duplicate id {item_id!r} among {among} (also {seen[item_id]})"
                )
            seen[item_id] = path

    def vehicle_types(self, value: Any, path: str) -> dict[str, VehicleTypeSpec]:
        if not isinstance(value, dict):
            raise self.error(
                path, f"expected a mapping of type name -> parameters, got {_describe(value)}"
            )
        types = {}
        for name, params in value.items():
            if not isinstance(name, str) or not name.strip():
                raise self.error(path, f"expected non-empty type names, got {_describe(name)}")
            types[name] = self.vehicle_type(name, params, _join(path, name))
        return types

    def vehicle_type(self, name: str, value: Any, path: str) -> VehicleTypeSpec:
        defaults = VehicleTypeSpec(name)
        keys = tuple(f.name for f in fields(VehicleTypeSpec) if f.name != "id")
        d = self.mapping(value, path, keys)
        params: dict[str, Any] = {
            "base": self.choice(d, "base", path, TRAFFIC_VEHICLE_BASES, "passenger")
        }
        for key in ("length", "width", "height"):
            params[key] = self.number(d, key, path, None, positive=True, optional=True)
        for key in ("max_speed", "accel", "decel", "emergency_decel", "tau", "speed_factor"):
            params[key] = self.number(d, key, path, getattr(defaults, key), positive=True)
        params["sigma"] = self.number(
            d, "sigma", path, defaults.sigma, non_negative=True, maximum=1.0
        )
        for key in keys:
            if key not in params:
                params[key] = self.number(d, key, path, getattr(defaults, key), non_negative=True)
        return VehicleTypeSpec(name, **params)

    def route_fields(self, d: dict, path: str) -> tuple[list[str] | None, str | None, str | None]:
        """Exactly one way to give the path: ``route`` (>= 1 roads) or origin and destination."""
        ends = [k for k in ("origin", "destination") if k in d]
        if "route" in d:
            if ends:
                raise self.error(
                    _join(path, ends[0]),
                    "not allowed with route: give either route or origin and destination",
                )
            route = self.string_list(d, "route", path, [])
            if not route:
                raise self.error(
                    _join(path, "route"), "expected a list of at least one road, got []"
                )
            return route, None, None
        if not ends:
            raise self.error(
                path, "expected a route (a list of roads) or origin and destination, got neither"
            )
        origin, destination = (self.road_id(d, key, path) for key in ("origin", "destination"))
        return None, origin, destination

    def road_id(self, d: dict, key: str, path: str) -> str:
        if key not in d:
            raise self.error(_join(path, key), "missing required field (a road id)")
        return self.string(d, key, path)

    def rate_fields(self, d: dict, path: str) -> tuple[float | None, float | None]:
        given = [k for k in ("rate", "probability") if k in d]
        if len(given) != 1:
            raise self.error(
                path,
                "expected exactly one of rate (vehicles per hour) or probability (departures per "
                f"second), got {'both' if given else 'neither'}",
            )
        rate = self.number(d, "rate", path, None, positive=True)
        probability = self.number(d, "probability", path, None, positive=True, maximum=1.0)
        return rate, probability

    def time_window(self, d: dict, path: str) -> tuple[float, float]:
        begin = self.number(d, "begin", path, 0.0, non_negative=True)
        end = self.number(d, "end", path, 3600.0)
        if end <= begin:
            raise self.error(
                _join(path, "end"), f"expected a time after begin ({begin:g} s), got {end:g}"
            )
        return begin, end

    def vehicle_type_ref(self, d: dict, path: str, declared: Mapping[str, Any]) -> str:
        name = self.string(d, "vehicle_type", path, "car")
        if name not in declared and name not in DEFAULT_VEHICLE_TYPES:
            known = ", ".join(declared) or "none"
            raise self.error(
                _join(path, "vehicle_type"),
                f"unknown vehicle type {name!r}; declared in traffic.vehicle_types: {known}; "
                f"always available: {', '.join(DEFAULT_VEHICLE_TYPES)}",
            )
        return name

    def depart_fields(self, d: dict, path: str) -> dict[str, Any]:
        lane = d.get("depart_lane", "best")
        lane_ok = (isinstance(lane, str) and lane in DEPART_LANES) or (
            isinstance(lane, int) and not isinstance(lane, bool) and lane >= 0
        )
        if not lane_ok:
            raise self.error(
                _join(path, "depart_lane"),
                f"expected one of {', '.join(DEPART_LANES)} or a lane index (an integer >= 0), "
                f"got {_describe(lane)}",
            )
        speed = d.get("depart_speed", "desired")
        if isinstance(speed, str) and speed in DEPART_SPEEDS:
            pass
        elif (
            isinstance(speed, (int, float))
            and not isinstance(speed, bool)
            and math.isfinite(speed)
            and speed >= 0
        ):
            speed = float(speed)
        else:
            raise self.error(
                _join(path, "depart_speed"),
                f"expected one of {', '.join(DEPART_SPEEDS)} or a speed in m/s (a number >= 0), "
                f"got {_describe(speed)}",
            )
        pos = self.number(d, "depart_pos", path, 0.0, non_negative=True)
        return {"depart_lane": lane, "depart_speed": speed, "depart_pos": pos}

    def flow(self, value: Any, path: str, declared: Mapping[str, Any]) -> FlowSpec:
        keys = (
            "id", "route", "origin", "destination", "rate", "probability", "begin", "end",
            "vehicle_type", "depart_lane", "depart_speed", "depart_pos",
        )  # fmt: skip
        d = self.mapping(value, path, keys)
        flow_id = self.string(d, "id", path)
        route, origin, destination = self.route_fields(d, path)
        rate, probability = self.rate_fields(d, path)
        begin, end = self.time_window(d, path)
        return FlowSpec(
            id=flow_id,
            route=route,
            origin=origin,
            destination=destination,
            rate=rate,
            probability=probability,
            begin=begin,
            end=end,
            vehicle_type=self.vehicle_type_ref(d, path, declared),
            **self.depart_fields(d, path),
        )

    def trip(self, value: Any, path: str, declared: Mapping[str, Any]) -> TripSpec:
        keys = (
            "id", "route", "origin", "destination", "depart", "vehicle_type", "depart_lane",
            "depart_speed", "depart_pos",
        )  # fmt: skip
        d = self.mapping(value, path, keys)
        trip_id = self.string(d, "id", path)
        route, origin, destination = self.route_fields(d, path)
        return TripSpec(
            id=trip_id,
            route=route,
            origin=origin,
            destination=destination,
            depart=self.number(d, "depart", path, 0.0, non_negative=True),
            vehicle_type=self.vehicle_type_ref(d, path, declared),
            **self.depart_fields(d, path),
        )

    def pedestrian(self, value: Any, path: str) -> PedestrianFlowSpec:
        keys = ("id", "origin", "destination", "rate", "probability", "begin", "end", "speed")
        d = self.mapping(value, path, keys)
        ped_id = self.string(d, "id", path)
        origin, destination = (self.road_id(d, key, path) for key in ("origin", "destination"))
        rate, probability = self.rate_fields(d, path)
        begin, end = self.time_window(d, path)
        return PedestrianFlowSpec(
            id=ped_id,
            origin=origin,
            destination=destination,
            rate=rate,
            probability=probability,
            begin=begin,
            end=end,
            speed=self.number(d, "speed", path, 1.3, positive=True),
        )

    def agents_and_traffic(self, agents: list[AgentSpec], traffic: TrafficSpec | None) -> None:
        """Checks that span both sections: taken-over trips, hand-back, clashing vehicle ids."""
        trips = {} if traffic is None else {t.id: t for t in traffic.trips}
        taken_by: dict[str, int] = {}
        for i, agent in enumerate(agents):
            where = f"agents[{i}].mission"
            trip_id = agent.mission.start.take_over
            if trip_id is not None:
                path = f"{where}.start.take_over"
                if traffic is None:
                    raise self.error(
                        path,
                        f"no trip {trip_id!r} to take over: the scenario has no traffic section",
                    )
                if trip_id not in trips:
                    hint = difflib.get_close_matches(trip_id, trips, n=1)
                    suggestion = f" (did you mean {hint[0]!r}?)" if hint else ""
                    raise self.error(
                        path,
                        f"unknown trip {trip_id!r}{suggestion}; traffic.trips: "
                        f"{', '.join(trips) or 'none'}",
                    )
                depart = trips[trip_id].depart
                if depart != 0.0:
                    raise self.error(
                        path,
                        f"trip {trip_id!r} departs at {depart:g} s; only a trip departing at 0 "
                        "exists at reset to be taken over",
                    )
                if trip_id in taken_by:
                    raise self.error(
                        path,
                        f"trip {trip_id!r} is already taken over by agents[{taken_by[trip_id]}]",
                    )
                taken_by[trip_id] = i
            if agent.mission.on_end == "traffic" and traffic is None:
                raise self.error(
                    f"{where}.on_end",
                    "'traffic' hands the vehicle to traffic, but the scenario has no traffic "
                    "section",
                )
        agent_index = {a.id: i for i, a in enumerate(agents)}
        for i, agent in enumerate(agents):
            lead = agent.mission.follow
            if lead is None:
                continue
            if lead == agent.id:
                raise self.error(f"agents[{i}].mission.follow", "an agent cannot follow itself")
            if lead not in trips and lead not in agent_index:
                known = [*trips, *agent_index]
                hint = difflib.get_close_matches(lead, known, n=1)
                suggestion = f" (did you mean {hint[0]!r}?)" if hint else ""
                raise self.error(
                    f"agents[{i}].mission.follow",
                    f"no vehicle {lead!r} to follow{suggestion}; traffic.trips and agents: "
                    f"{', '.join(known) or 'none'}",
                )
        for j, trip in enumerate(traffic.trips if traffic is not None else []):
            if trip.id in agent_index:
                raise self.error(
                    f"traffic.trips[{j}].id",
                    f"{trip.id!r} is also the id of agents[{agent_index[trip.id]}]; "
                    "vehicle ids must be unique",
                )

    def comms(self, value: Any, agents: list[AgentSpec]) -> CommsConfig:
        """The V2V settings, validated by ``smarts.comms`` (errors name ``comms.<field>``)."""
        from smarts.comms.config import CommsConfig

        where = f"{self.source}: comms"
        config = CommsConfig.from_dict(value, where=where)
        config.check_agents([a.id for a in agents], where=where)
        return config

    def events(self, value: Any) -> EventsSpec:
        path = "events"
        d = self.mapping(value, path, ("terminate_on", "not_moving_seconds", "not_moving_distance"))
        terminate_on = self.string_list(d, "terminate_on", path, list(DEFAULT_TERMINATE_ON))
        for i, name in enumerate(terminate_on):
            if name not in TERMINATION_EVENTS:
                raise self.error(
                    f"{path}.terminate_on[{i}]",
                    f"expected one of {', '.join(TERMINATION_EVENTS)}; got {name!r}",
                )
            if name in terminate_on[:i]:
                raise self.error(f"{path}.terminate_on[{i}]", f"{name!r} is listed twice")
        return EventsSpec(
            terminate_on=terminate_on,
            not_moving_seconds=self.number(d, "not_moving_seconds", path, 60.0, positive=True),
            not_moving_distance=self.number(d, "not_moving_distance", path, 1.0, non_negative=True),
        )

    def reward(self, value: Any) -> RewardSpec:
        path = "reward"
        keys = (
            "progress_weight",
            "collision_penalty",
            "off_road_penalty",
            "goal_bonus",
            "step_penalty",
        )
        d = self.mapping(value, path, keys)
        defaults = RewardSpec()
        return RewardSpec(
            **{k: self.number(d, k, path, getattr(defaults, k), non_negative=True) for k in keys}
        )


class _MapChecker:
    """Checks mission references against a compiled map, with errors naming the field."""

    def __init__(self, source: str, road_map: Any) -> None:
        self.source = source
        self.map = road_map
        self.map_name = Path(str(getattr(road_map, "source", "") or "map")).name

    def error(self, path: str, message: str) -> ScenarioError:
        return ScenarioError(f"{self.source}: {path}: {message}")

    def road(self, path: str, road: str) -> Any:
        index = self.map.road_index_of.get(road)
        if index is None:
            normal = sorted(r for r in self.map.road_index_of if not r.startswith(":"))
            hint = difflib.get_close_matches(road, normal, n=1)
            suggestion = f" (did you mean {hint[0]!r}?)" if hint else ""
            shown = ", ".join(normal[:30]) + (", ..." if len(normal) > 30 else "")
            raise self.error(
                path, f"map {self.map_name!r} has no road {road!r}{suggestion}; roads: {shown}"
            )
        lanes = self.map.road_lanes(index)
        internal = getattr(self.map, "lane_internal", None)
        if road.startswith(":") or (
            internal is not None and len(lanes) and bool(internal[lanes[0]])
        ):
            raise self.error(path, f"road {road!r} lies inside a junction; name a normal road")
        return lanes

    def road_lane(self, path: str, road: str, lane: int | None, offset: float | None) -> None:
        lanes = self.road(f"{path}.road", road)
        self.lane_offset(road, lanes, lane, offset, f"{path}.lane", f"{path}.offset", "offset")

    def lane_offset(
        self,
        road: str,
        lanes: Any,
        lane: int | None,
        offset: float | None,
        lane_path: str,
        offset_path: str,
        offset_name: str,
    ) -> None:
        """The lane exists on the road and the offset lies on it (on every lane when None)."""
        n = len(lanes)
        if lane is not None and lane >= n:
            raise self.error(lane_path, f"road {road!r} has {n} lanes (0..{n - 1}), got {lane}")
        if offset is None:
            return
        candidates = [lanes[lane]] if lane is not None else list(lanes)
        length = min(float(self.map.lane_length[i]) for i in candidates)
        if offset > length:
            which = f"lane {lane} of road {road!r}" if lane is not None else f"road {road!r}"
            raise self.error(
                offset_path, f"{which} is {length:.1f} m long, got {offset_name} {offset:g}"
            )

    def traffic(self, traffic: TrafficSpec) -> None:
        """Every road of every flow, trip and pedestrian flow; the departure lane and position."""
        for kind, items in (("flows", traffic.flows), ("trips", traffic.trips)):
            for i, item in enumerate(items):
                path = f"traffic.{kind}[{i}]"
                if item.route is not None:
                    found = [self.road(f"{path}.route[{j}]", r) for j, r in enumerate(item.route)]
                    first_lanes = found[0]
                else:
                    first_lanes = self.road(f"{path}.origin", item.origin)
                    self.road(f"{path}.destination", item.destination)
                lane = item.depart_lane if isinstance(item.depart_lane, int) else None
                self.lane_offset(
                    item.roads[0],
                    first_lanes,
                    lane,
                    item.depart_pos,
                    f"{path}.depart_lane",
                    f"{path}.depart_pos",
                    "depart_pos",
                )
        for i, ped in enumerate(traffic.pedestrians):
            self.road(f"traffic.pedestrians[{i}].origin", ped.origin)
            self.road(f"traffic.pedestrians[{i}].destination", ped.destination)

    def position(self, path: str, xy: tuple[float, float], radius: float) -> None:
        bounds = getattr(self.map, "bounds", None)
        if bounds is None:
            return
        xmin, ymin, xmax, ymax = (float(b) for b in bounds)
        x, y = xy
        if not (xmin - radius <= x <= xmax + radius and ymin - radius <= y <= ymax + radius):
            raise self.error(
                path,
                f"({x:g}, {y:g}) lies outside the map bounds x {xmin:.1f}..{xmax:.1f}, "
                f"y {ymin:.1f}..{ymax:.1f}",
            )
