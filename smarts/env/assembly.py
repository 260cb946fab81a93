"""Assemble a runnable simulation from a scenario spec.

This is the one place that knows every provider kind: the step loop in ``smarts.core`` only sees the
provider protocol, so adding traffic or replay providers changes this file, not the loop.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np

from smarts.core.errors import ScenarioError
from smarts.core.events import NUM_EVENTS, event_from_name
from smarts.core.missions import resolve_mission
from smarts.core.provider import ProviderBase
from smarts.core.spec import REPLAY_MAP
from smarts.core.spec import ScenarioSpec as PlainScenarioSpec
from smarts.core.simulation import EventConfig, Simulation, check_seed
from smarts.core.vehicle_table import Role, VehicleType
from smarts.dynamics.action_spaces import ActionSpaceType
from smarts.dynamics.agent_provider import AgentProvider, AgentVehicle
from smarts.dynamics.lane_relative import LaneRelativeParams
from smarts.dynamics.limits import ReachLimits
from smarts.maps import RoadMap, load_map
from smarts.scenario import ScenarioSpec, load_scenario
from smarts.traffic.signals import FixedTimeSignals, SignalState


def as_spec(scenario: str | Path | PlainScenarioSpec) -> ScenarioSpec:
    """A spec from a library name, a YAML path or a spec object (a plain ``smarts.core.spec``
    dataclass gains the reader's ``map_path`` and ``check_map``; its fields are kept as they are)."""
    if isinstance(scenario, ScenarioSpec):
        return scenario
    if isinstance(scenario, PlainScenarioSpec):
        return ScenarioSpec(**{f.name: getattr(scenario, f.name) for f in dataclasses.fields(scenario)})
    return load_scenario(scenario)


def scenario_map(spec: ScenarioSpec) -> RoadMap:
    if spec.map == REPLAY_MAP and spec.replay is not None:  # the dataset's own lanes
        from smarts.replay import replay_road_map

        road_map = replay_road_map(spec.replay, spec.base_dir, spec.source)
        spec.check_map(road_map)
        return road_map
    road_map = load_map(spec.map_path())
    spec.check_map(road_map)
    return road_map


def build_simulation(
    spec: ScenarioSpec,
    limits: ReachLimits | None = None,
    road_map: RoadMap | None = None,
    lane_relative: LaneRelativeParams | None = None,
) -> Simulation:
    road_map = road_map or scenario_map(spec)
    limits = limits or ReachLimits()
    replay = _replay_plan(spec)
    taken = {t.agent_id: t for t in replay.take_overs} if replay is not None else {}
    missions = [
        resolve_mission(
            road_map, agent.id, _replay_mission(road_map, taken, agent, f"{spec.source}: replay.take_over.{agent.id}"),
            f"{spec.source}: agents[{i}].mission", spec.traffic,
        )
        for i, agent in enumerate(spec.agents)
    ]
    vehicles = []
    for agent in spec.agents:
        dims = agent.vehicle.dimensions()
        vehicles.append(
            AgentVehicle(
                agent_id=agent.id,
                action_space=ActionSpaceType(agent.action_space),
                vtype=VehicleType[agent.vehicle.type.upper()],
                length=dims.length,
                width=dims.width,
                height=dims.height,
                mass=dims.mass,
                role=Role.SOCIAL_AGENT if agent.is_social else Role.AGENT,
                take_over=taken[agent.id].table_id if agent.id in taken else agent.mission.start.take_over,
                controller=agent.controller,
            )
        )
    terminate = np.zeros(NUM_EVENTS, dtype=bool)
    for name in spec.events.terminate_on:
        terminate[event_from_name(name)] = True
    events = EventConfig(
        terminate_on=terminate,
        not_moving_seconds=spec.events.not_moving_seconds,
        not_moving_distance=spec.events.not_moving_distance,
    )
    signals = SignalState(road_map) if road_map.tls_ids else None
    providers = [AgentProvider(vehicles, limits, spec.step_length, lane_relative)]
    providers += traffic_providers(spec, road_map, signals)
    if replay is not None:
        providers.insert(1, _replay_provider(spec, replay, road_map, providers, signals))
    sim = Simulation(
        road_map,
        missions,
        providers,
        dt=spec.step_length,
        episode_steps=spec.episode_steps,
        events=events,
        capacity=spec.vehicle_capacity,
        seed=check_seed(spec.seed, f"{spec.source}: seed"),
    )
    sim.signals = signals
    return sim


def _replay_plan(spec: ScenarioSpec):
    """The scenario's replay section checked against its recording (None without one)."""
    if spec.replay is None:
        return None
    from smarts.replay.load import check_capacity, plan_replay

    plan = plan_replay(spec.replay, spec.base_dir, spec.source)
    check_capacity(plan, spec.vehicle_capacity, len(spec.agents), spec.source)
    return plan


def _replay_mission(road_map: RoadMap, taken: dict, agent, where: str):
    """An agent's mission; one taking over a recorded vehicle starts in it and ends where it did."""
    if agent.id not in taken:
        return agent.mission
    from smarts.replay import take_over_mission

    return take_over_mission(road_map, taken[agent.id], where)


def _replay_provider(spec: ScenarioSpec, replay, road_map: RoadMap, providers: list, signals):
    """The replay provider, stepped right after the agents; reactive vehicles are handed to the
    scenario's traffic engine, or to a built-in traffic model with no flows of its own."""
    from smarts.replay import ReplayProvider

    target = None
    if spec.replay.reactive != "off":
        target = next((p for p in providers[1:] if type(p).can_accept is not ProviderBase.can_accept), None)
        if target is None:
            from smarts.core.spec.traffic import TrafficSpec
            from smarts.traffic.builtin import BuiltinTrafficProvider

            target = BuiltinTrafficProvider(TrafficSpec(), road_map, spec.step_length, signals)
            providers.append(target)
    return ReplayProvider(
        replay.recording, replay.start, replay.duration, reactive=spec.replay.reactive,
        reactive_distance=spec.replay.reactive_distance, reactive_target=target,
    )  # fmt: skip


def traffic_providers(spec: ScenarioSpec, road_map: RoadMap, signals: SignalState | None) -> list:
    """The providers that move everything but the agents, in stepping order (after the agents).

    SUMO drives its own signals; without SUMO the map's fixed-time programs run (also when the
    scenario has no traffic, so observations and metrics still see the lights change).
    """
    try:
        return _traffic_providers(spec, road_map, signals)
    except ScenarioError as err:  # name the scenario file, as every spec error does
        message = str(err)
        raise ScenarioError(message if message.startswith(spec.source) else f"{spec.source}: {message}") from None


def _traffic_providers(spec: ScenarioSpec, road_map: RoadMap, signals: SignalState | None) -> list:
    traffic = spec.traffic
    if traffic is not None and traffic.engine == "sumo":
        from smarts.maps import sumo_net_path
        from smarts.traffic.sumo_provider import SumoTrafficProvider

        net_file = sumo_net_path(spec.map_path())
        return [SumoTrafficProvider(traffic, road_map, net_file, spec.step_length, signals)]
    providers = [FixedTimeSignals(signals)] if signals is not None else []
    if traffic is not None:
        from smarts.traffic.builtin import BuiltinTrafficProvider

        providers.append(BuiltinTrafficProvider(traffic, road_map, spec.step_length, signals))
    return providers
