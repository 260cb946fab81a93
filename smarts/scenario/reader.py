"""Reading a scenario: YAML or a plain mapping into the spec dataclasses (``smarts.core.spec``),
strictly validated.

Validation happens once, when the file is read, so the simulator can trust every field. Each error
names the file and the dotted field path (``agents[1].mission.goal.radius``) and says what was
expected, because a scenario author should never have to guess which line is wrong.
"""

from __future__ import annotations

import difflib
import math
import os
from collections.abc import Mapping
from dataclasses import fields
from pathlib import Path
from typing import TYPE_CHECKING, Any

import yaml

from smarts.core.errors import InterfaceError, ScenarioError
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
from smarts.sensors.interface import AgentInterface, interface_from_dict

if TYPE_CHECKING:  # the reader imports it only for scenarios with a comms section
    from smarts.comms.config import CommsConfig

MAP_FILE_SUFFIXES = (".net.xml", ".xodr")
ZOO_PREFIX = "zoo:"


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
    return _Reader(source, None if base_dir is None else Path(base_dir), spec_class).scenario(data)


def read_scenario_file(
    path: str | os.PathLike, spec_class: type[ScenarioSpec] = ScenarioSpec
) -> ScenarioSpec:
    """Read and validate a scenario YAML file; its name defaults to the file's name."""
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
    return read_scenario(data, source, path.parent, spec_class)


def resolve_map_file(map_value: str, base_dir: Path | None) -> Path:
    """A map file named by a scenario: relative paths are resolved against ``base_dir`` (the
    scenario file's folder; the current directory when None)."""
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

    def __init__(self, source: str, base_dir: Path | None, spec_class: type[ScenarioSpec]) -> None:
        self.source = source
        self.base_dir = base_dir
        self.spec_class = spec_class

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
        return self.spec_class(
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
        path = resolve_map_file(value, self.base_dir)
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
