"""Writing a scenario: the spec models as plain data and YAML that the reader turns back into an
equal spec (written the way people write them: defaults of optional parts left out)."""

from __future__ import annotations

from typing import Any

import yaml

from smarts.core.spec.comms import CommsConfig
from smarts.core.spec.interface import interface_to_dict
from smarts.core.spec.replay import ReplaySpec
from smarts.core.spec.scenario import AgentSpec, ScenarioSpec
from smarts.core.spec.traffic import TrafficSpec


def scenario_to_dict(spec: ScenarioSpec) -> dict[str, Any]:
    """Plain data (lists, dicts, scalars) that ``read_scenario`` turns back into an equal spec."""
    data = _scenario_dict(spec)
    if spec.replay is not None:
        data["replay"] = replay_to_dict(spec.replay)
        taken = spec.replay.take_over
        for agent in data["agents"]:
            if agent["id"] in taken:  # its mission comes from the recorded vehicle's track
                del agent["mission"]
    return data


def _scenario_dict(spec: ScenarioSpec) -> dict[str, Any]:
    return {
        "name": spec.name,
        "map": spec.map,
        "step_length": spec.step_length,
        "episode_steps": spec.episode_steps,
        "seed": spec.seed,
        "vehicle_capacity": spec.vehicle_capacity,
        "agents": [_agent_dict(a) for a in spec.agents],
        "events": {
            "terminate_on": list(spec.events.terminate_on),
            "not_moving_seconds": spec.events.not_moving_seconds,
            "not_moving_distance": spec.events.not_moving_distance,
        },
        "reward": {
            "progress_weight": spec.reward.progress_weight,
            "collision_penalty": spec.reward.collision_penalty,
            "off_road_penalty": spec.reward.off_road_penalty,
            "goal_bonus": spec.reward.goal_bonus,
            "step_penalty": spec.reward.step_penalty,
        },
        "traffic": None if spec.traffic is None else _traffic_dict(spec.traffic),
        "comms": None if spec.comms is None else _comms_dict(spec.comms),
    }


def scenario_to_yaml(spec: ScenarioSpec) -> str:
    return yaml.dump(scenario_to_dict(spec), Dumper=_SpecDumper, sort_keys=False)


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
    """A traffic model as a mapping, leaving out unset (None) fields and those in ``drop``."""
    out = {}
    for name in type(item).model_fields:
        value = getattr(item, name)
        if value is None or name in drop:
            continue
        out[name] = list(value) if isinstance(value, list) else value
    return out


def _traffic_dict(traffic: TrafficSpec) -> dict[str, Any]:
    return {
        "engine": traffic.engine,
        "density": traffic.density,
        "vehicle_types": {name: _without_none(vtype, drop=("id",)) for name, vtype in traffic.vehicle_types.items()},
        "flows": [_without_none(flow) for flow in traffic.flows],
        "trips": [_without_none(trip) for trip in traffic.trips],
        "pedestrians": [_without_none(ped) for ped in traffic.pedestrians],
    }


def _comms_dict(comms: CommsConfig) -> dict[str, Any]:
    """Every comms field (a default written out reads back the same)."""
    out = {name: getattr(comms, name) for name in CommsConfig.model_fields}
    out["agent_channels"] = dict(comms.agent_channels)
    return out


def replay_to_dict(replay: ReplaySpec) -> dict[str, Any]:
    """The replay section as plain data that reads back into an equal spec (defaults left out)."""
    out: dict[str, Any] = {"format": replay.format, "path": replay.path}
    defaults = ReplaySpec(format=replay.format, path=replay.path)
    for key in ("start", "duration", "vehicles", "reactive", "reactive_distance", "coordinates", "swap_xy",
                "flip_y", "scenario"):  # fmt: skip
        value = getattr(replay, key)
        if value != getattr(defaults, key):
            out[key] = list(value) if isinstance(value, list) else value
    if replay.take_over:
        out["take_over"] = dict(replay.take_over)
    if tuple(replay.offset) != (0.0, 0.0):
        out["offset"] = list(replay.offset)
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
