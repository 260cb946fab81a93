"""Assemble a runnable simulation from a scenario spec.

This is the one place that knows every provider kind: the step loop in ``smarts.core`` only sees the
provider protocol, so adding traffic or replay providers changes this file, not the loop.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import numpy as np

from smarts.core.errors import ScenarioError
from smarts.core.events import NUM_EVENTS, event_from_name
from smarts.core.missions import resolve_mission
from smarts.core.provider import ProviderBase
from smarts.core.simulation import EpisodeSetup, EventConfig, Simulation, check_seed
from smarts.core.spec import REPLAY_MAP
from smarts.core.vehicle_table import Role, VehicleType
from smarts.dynamics.action_spaces import ActionSpaceType
from smarts.dynamics.agent_provider import AgentProvider, AgentVehicle
from smarts.dynamics.lane_relative import LaneRelativeParams
from smarts.dynamics.limits import ReachLimits
from smarts.maps import RoadMap, load_map
from smarts.maps.stack import stack_maps
from smarts.scenario import ScenarioSpec, check_map, load_scenario, map_path
from smarts.traffic.signals import FixedTimeSignals, SignalState


def as_spec(scenario: str | Path | ScenarioSpec) -> ScenarioSpec:
    """A spec from a library name, a YAML path or a spec object (returned as it is)."""
    if isinstance(scenario, ScenarioSpec):
        return scenario
    return load_scenario(scenario)


def scenario_map(spec: ScenarioSpec) -> RoadMap:
    if spec.map == REPLAY_MAP and spec.replay is not None:  # the dataset's own lanes
        from smarts.replay import replay_road_map

        road_map = replay_road_map(spec.replay, spec.base_dir, spec.source)
        check_map(spec, road_map)
        return road_map
    road_map = load_map(map_path(spec))
    check_map(spec, road_map)
    return road_map


def build_simulation(
    specs: ScenarioSpec | Sequence[ScenarioSpec],
    limits: ReachLimits | None = None,
    road_map: RoadMap | None = None,
    lane_relative: LaneRelativeParams | None = None,
    *,
    seeds: Sequence[int] | None = None,
    device: str = "cpu",
) -> Simulation:
    """One simulation of ``specs`` (one scenario: a single episode; a list: episode ``b`` runs
    ``specs[b]`` with seed ``seeds[b]``, default each scenario's seed). Scenarios on different
    maps share it through a stack of their maps (``smarts.maps.stack``). ``road_map``: the map of
    every scenario, when it is loaded already. ``device``: where stages with a torch version run
    (``smarts.dynamics.pose_control_torch.resolve_device``; "cpu": the compiled kernels)."""
    torch_device = None  # the compiled kernels: no torch import (seconds) for a simulation on "cpu"
    if device != "cpu":
        from smarts.dynamics.pose_control_torch import resolve_device

        torch_device = resolve_device(device)
    specs = [specs] if not isinstance(specs, (list, tuple)) else list(specs)
    if not specs:
        raise ValueError("build_simulation needs at least one scenario")
    seeds = [s.seed for s in specs] if seeds is None else list(seeds)
    if len(seeds) != len(specs):
        raise ValueError(f"seeds: expected {len(specs)} seeds (one per scenario), got {len(seeds)}")
    first = specs[0]
    limits = limits or ReachLimits()
    for spec in specs[1:]:
        if spec.step_length != first.step_length:
            raise ScenarioError(
                f"{spec.source}: step_length {spec.step_length} differs from {first.source}'s "
                f"{first.step_length}; the episodes of one simulation share the step"
            )
    map_number: dict = {}
    maps: list[RoadMap] = []
    for spec in specs:
        key = _map_key(spec)
        if key not in map_number:
            if road_map is not None and maps:
                raise ScenarioError(
                    f"{spec.source}: map {spec.map} differs from {first.source}'s, but one road_map was given for all"
                )
            map_number[key] = len(maps)
            maps.append(road_map if road_map is not None else scenario_map(spec))
    stack = stack_maps(maps)
    vehicles: list[AgentVehicle] = []
    episodes: list[EpisodeSetup] = []
    built: dict = {}  # missions and traffic compiled so far: later episodes of a scenario reuse them
    for b, spec in enumerate(specs):
        m = map_number[_map_key(spec)]
        episode_map = stack.windows[m]  # the scenario's map in the simulation's lane indices
        setup, agents = _episode(spec, episode_map, check_seed(seeds[b], f"{spec.source}: seed"), limits, built)
        setup.map_index = m
        episodes.append(setup)
        vehicles += agents
    providers = [AgentProvider(vehicles, limits, first.step_length, lane_relative, torch_device)]
    capacity = max(s.vehicle_capacity for s in specs)
    return Simulation(stack, episodes, providers, dt=first.step_length, capacity=capacity)


def _map_key(spec: ScenarioSpec) -> tuple:
    """What makes two scenarios' maps the same map: the file (and, for a dataset's own lanes,
    the scenario of the recording)."""
    if spec.map == REPLAY_MAP and spec.replay is not None:
        return (str(map_path(spec)), spec.replay.scenario)
    return (str(map_path(spec)),)


def _episode(
    spec: ScenarioSpec, road_map: RoadMap, seed: int, limits: ReachLimits, built: dict | None = None
) -> tuple[EpisodeSetup, list[AgentVehicle]]:
    """One episode of ``spec`` on ``road_map`` (its window of the simulation's maps): its
    missions, own providers, rules and signals, and its agents' vehicles. ``built``: what earlier
    episodes of the same simulation built, reused for the same mission or traffic on the same map
    (neither depends on the seed): resolved missions (their arrays read-only) and compiled
    built-in traffic."""
    replay = _replay_plan(spec)
    taken = {t.agent_id: t for t in replay.take_overs} if replay is not None else {}
    built = {} if built is None else built
    missions = []
    for i, agent in enumerate(spec.agents):
        mission = _replay_mission(road_map, taken, agent, f"{spec.source}: replay.take_over.{agent.id}")
        where = f"{spec.source}: agents[{i}].mission"
        key = ("mission", id(road_map), id(mission), id(spec.traffic), agent.id, where)
        kept = built.get(key)
        if kept is None or kept[0] is not mission or kept[1] is not spec.traffic:  # (the same objects)
            kept = built[key] = (mission, spec.traffic, _read_only(resolve_mission(road_map, agent.id, mission,
                                                                                   where, spec.traffic)))  # fmt: skip
        missions.append(kept[2])
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
    providers = traffic_providers(spec, road_map, signals, built)
    if replay is not None:
        providers.insert(0, _replay_provider(spec, replay, road_map, providers, signals))
    setup = EpisodeSetup(
        missions, providers, episode_steps=spec.episode_steps, events=events, seed=seed, signals=signals
    )
    return setup, vehicles


def _replay_plan(spec: ScenarioSpec):
    """The scenario's replay section checked against its recording (None without one)."""
    if spec.replay is None:
        return None
    from smarts.replay.load import check_capacity, plan_replay

    plan = plan_replay(spec.replay, spec.base_dir, spec.source)
    check_capacity(plan, spec.vehicle_capacity, len(spec.agents), spec.source)
    return plan


def _read_only(mission):
    """``mission`` with its arrays made read-only (it may be shared by several episodes)."""
    for value in vars(mission).values():
        if isinstance(value, np.ndarray):
            value.flags.writeable = False
    return mission


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
        target = next((p for p in providers if type(p).can_accept is not ProviderBase.can_accept), None)
        if target is None:
            from smarts.core.spec.traffic import TrafficSpec
            from smarts.traffic.builtin import BuiltinTrafficProvider

            target = BuiltinTrafficProvider(TrafficSpec(), road_map, spec.step_length, signals)
            providers.append(target)
    return ReplayProvider(
        replay.recording, replay.start, replay.duration, reactive=spec.replay.reactive,
        reactive_distance=spec.replay.reactive_distance, reactive_target=target,
    )  # fmt: skip


def traffic_providers(
    spec: ScenarioSpec, road_map: RoadMap, signals: SignalState | None, built: dict | None = None
) -> list:
    """The providers that move everything but the agents, in stepping order (after the agents).

    SUMO drives its own signals; without SUMO the map's fixed-time programs run (also when the
    scenario has no traffic, so observations and metrics still see the lights change). ``built``:
    see :func:`_episode` (the built-in traffic compiled for an earlier episode is reused).
    """
    try:
        return _traffic_providers(spec, road_map, signals, built)
    except ScenarioError as err:  # name the scenario file, as every spec error does
        message = str(err)
        raise ScenarioError(message if message.startswith(spec.source) else f"{spec.source}: {message}") from None


def _traffic_providers(spec: ScenarioSpec, road_map: RoadMap, signals: SignalState | None, built: dict | None) -> list:
    traffic = spec.traffic
    if traffic is not None and traffic.engine == "sumo":
        from smarts.maps import sumo_net_path
        from smarts.traffic.sumo_provider import SumoTrafficProvider

        net_file = sumo_net_path(map_path(spec))
        return [SumoTrafficProvider(traffic, road_map, net_file, spec.step_length, signals)]
    providers = [FixedTimeSignals(signals)] if signals is not None else []
    if traffic is not None:
        from smarts.traffic.builtin import BuiltinTrafficProvider

        providers.append(BuiltinTrafficProvider(traffic, road_map, spec.step_length, signals, compiled=built))
    return providers
