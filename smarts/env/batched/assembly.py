"""Build a ``BatchedSimulation`` from scenario specs: the agents of every episode under one
agent provider, each episode's traffic and signals as its own providers.

The batched backend covers what can be stepped for all episodes at once; anything else is refused
here with a ``BatchedSetupError`` naming the scenario and the field, so a run never silently
falls back to something else. SUMO traffic in particular stays on the per-env path: libsumo runs
one simulation per process.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import torch

from smarts.core.batched import BatchedSimulation
from smarts.core.errors import ActionError, ScenarioError
from smarts.core.events import NUM_EVENTS, event_from_name
from smarts.core.missions import resolve_mission
from smarts.core.simulation import EventConfig, check_seed
from smarts.core.vehicle_table import Role, VehicleType
from smarts.dynamics.action_spaces import ActionSpaceType, action_components
from smarts.dynamics.agent_provider import AgentProvider, AgentVehicle
from smarts.dynamics.lane_relative import LaneRelativeParams
from smarts.dynamics.limits import ReachLimits
from smarts.dynamics.pose_control_torch import apply_pose_torch, resolve_device
from smarts.env.assembly import scenario_map, traffic_providers
from smarts.maps import RoadMap
from smarts.maps.stack import stack_maps
from smarts.scenario import ScenarioSpec
from smarts.traffic.signals import SignalState

BATCHED_ACTION_SPACES = (ActionSpaceType.RELATIVE_TARGET_POSE, ActionSpaceType.TARGET_POSE)


class BatchedSetupError(ScenarioError):
    """A scenario (or option) the batched backend cannot step; the message says what to use."""


def check_batchable(spec: ScenarioSpec) -> None:
    """Raise ``BatchedSetupError`` naming the field when ``spec`` needs the per-env path."""
    where = spec.source
    if spec.traffic is not None and spec.traffic.engine == "sumo":
        raise BatchedSetupError(
            f"{where}: traffic.engine: sumo runs one simulation per process (libsumo) and cannot be "
            "batched; use the per-env backend (--backend per_env) or engine: builtin"
        )
    if spec.comms is not None:
        raise BatchedSetupError(f"{where}: comms: V2V messages are not supported by the batched backend; use the per-env backend")
    for i, agent in enumerate(spec.agents):
        if agent.is_social:
            raise BatchedSetupError(
                f"{where}: agents[{i}].policy: social agents are not supported by the batched backend; use the per-env backend"
            )
        kind = ActionSpaceType(agent.action_space)
        if kind not in BATCHED_ACTION_SPACES:
            raise BatchedSetupError(
                f"{where}: agents[{i}].action_space: {kind.value} is not supported by the batched backend "
                f"(supported: {', '.join(k.value for k in BATCHED_ACTION_SPACES)}); use the per-env backend"
            )
        if agent.mission.start.take_over is not None:
            raise BatchedSetupError(f"{where}: agents[{i}].mission.start.take_over is not supported by the batched backend")
        if agent.mission.on_end == "traffic":
            raise BatchedSetupError(f"{where}: agents[{i}].mission.on_end: traffic is not supported by the batched backend")


class BatchedAgentProvider(AgentProvider):
    """The agent provider of all episodes: one action space and controller for every agent, the
    actions as one ``[agents, k]`` array (``BatchedSimulation.action_array``), and resets per episode.

    ``device``: a torch device for the stages that have a torch version (the pose controller,
    ``smarts.dynamics.pose_control_torch``); None runs the compiled numpy kernels."""

    def __init__(self, vehicles: list[AgentVehicle], limits: ReachLimits, dt: float,
                 lane_relative: LaneRelativeParams | None = None, device: torch.device | None = None):  # fmt: skip
        super().__init__(vehicles, limits, dt, lane_relative)
        self.device = device
        kinds = {(v.action_space, v.controller) for v in vehicles}
        if len(kinds) != 1:
            raise BatchedSetupError(
                f"the batched backend steps one action space and controller for every agent; got {sorted((k.value, c) for k, c in kinds)}"
            )
        ((self.kind, self.controller),) = kinds
        self.width = len(action_components(self.kind, self.controller))

    def reset(self, sim) -> None:  # episodes are reset one by one (reset_episode)
        self._planned = None

    def reset_episode(self, sim: BatchedSimulation, b: int, agents: np.ndarray) -> None:
        """Put episode ``b``'s agents at their starts (the first rows of its block, in agent order,
        as ``AgentProvider.reset`` does in a single simulation) and clear their controller state."""
        self._planned = None
        self.lane_offset[agents] = 0
        ctl = self.lane_relative
        if ctl is not None:
            if ctl._route_road is None:
                ctl.reset(sim)
            ctl.track[agents] = -1
            ctl.pending[agents] = 0
            ctl.profile_start[agents] = 0.0
            ctl.profile_age[agents] = np.inf
            ctl.branch[agents] = 0
        view = sim.views[b].table
        base = b * sim.episode_capacity
        for a in agents.tolist():
            vehicle, mission = self.vehicles[a], sim.missions[a]
            x, y = mission.start_xy
            row = view.add(
                sim.local_agent_ids[a], owner=self.provider_id, role=vehicle.role, x=float(x), y=float(y),
                heading=mission.start_heading, speed=mission.start_speed, vtype=vehicle.vtype,
                length=vehicle.length, width=vehicle.width, height=vehicle.height,
            )  # fmt: skip
            sim.agent_row[a] = base + row

    def check_actions(self, sim, actions, agents=None) -> None:
        members = sim.active_agents if agents is None else agents
        arr = np.asarray(actions)
        if arr.ndim != 2 or arr.shape[0] != len(sim.agent_ids) or arr.shape[1] != self.width:
            raise ActionError(
                f"expected actions of shape ({len(sim.agent_ids)}, {self.width}) (agents, "
                f"{', '.join(action_components(self.kind, self.controller))}), got {arr.shape}",
                [],
            )
        if arr.dtype.kind not in "fiu":
            raise ActionError(f"expected real-number actions, got dtype {arr.dtype}", [])
        finite = np.isfinite(arr[members]).all(axis=1)
        if not finite.all():
            bad = [sim.agent_ids[a] for a in members[~finite].tolist()]
            raise ActionError(f"actions of agents {bad} (episode/agent) are not finite numbers", bad)

    def step(self, sim, dt: float) -> None:
        members = sim.active_agents
        if members.size == 0:
            return
        rows = sim.agent_row[members]
        actions = np.asarray(sim.action_array[members], dtype=np.float64)
        if self.controller == "lane_relative":
            actions = self._from_commands(self.kind, sim, members, rows, actions, dt)
        if self.device is not None:
            world_frame = self.kind is ActionSpaceType.TARGET_POSE
            apply_pose_torch(sim.table, rows, actions, world_frame, dt, self.limits, self.device)
        else:
            self._drive(self.kind, sim, members, rows, actions, dt)


def build_batched_simulation(
    specs: list[ScenarioSpec],
    seeds: list[int],
    *,
    limits: ReachLimits | None = None,
    road_map: RoadMap | None = None,
    lane_relative: LaneRelativeParams | None = None,
    batch_traffic: bool = True,
    device: str = "cpu",
) -> BatchedSimulation:
    """One ``BatchedSimulation`` of ``len(specs)`` episodes, episode ``b`` of ``specs[b]`` with
    seed ``seeds[b]``. Scenarios on different maps share the batch through a stack of their maps
    (``smarts.maps.stack``). ``road_map``: the map of every scenario (when they all run on one
    map already loaded). ``batch_traffic``: step the built-in traffic of all episodes in one call
    (``smarts.env.batched.traffic``); False steps it episode by episode. ``device``: where stages
    with a torch version run (``smarts.dynamics.pose_control_torch.resolve_device``; "cpu": the
    compiled kernels)."""
    torch_device = resolve_device(device)
    for spec in specs:
        check_batchable(spec)
    first = specs[0]
    limits = limits or ReachLimits()
    for spec in specs[1:]:
        for field in ("step_length", "events"):
            if getattr(spec, field) != getattr(first, field):
                raise BatchedSetupError(f"{spec.source}: {field} differs from {first.source}'s; episodes of one batch share it")
    map_number: dict = {}
    maps: list[RoadMap] = []
    for spec in specs:
        if spec.map_path() not in map_number:
            if road_map is not None and maps:
                raise BatchedSetupError(f"{spec.source}: map {spec.map} differs from {first.source}'s, but one road_map was given for all")
            map_number[spec.map_path()] = len(maps)
            maps.append(road_map if road_map is not None else scenario_map(spec))
    stack = stack_maps(maps)
    episode_map = [map_number[spec.map_path()] for spec in specs]
    missions, vehicles, episode_providers, signals = [], [], [], []
    for spec, m in zip(specs, episode_map):
        road_map = stack.windows[m]  # the scenario's map in the batch's lane indices
        missions.append([
            resolve_mission(road_map, agent.id, agent.mission, f"{spec.source}: agents[{i}].mission", spec.traffic)
            for i, agent in enumerate(spec.agents)
        ])  # fmt: skip
        for agent in spec.agents:
            dims = agent.vehicle.dimensions()
            vehicles.append(AgentVehicle(
                agent_id="", action_space=ActionSpaceType(agent.action_space),
                vtype=VehicleType[agent.vehicle.type.upper()], length=dims.length, width=dims.width,
                height=dims.height, mass=dims.mass, role=Role.AGENT, controller=agent.controller,
            ))  # fmt: skip
        state = SignalState(road_map) if road_map.tls_ids else None
        signals.append(state)
        episode_providers.append(traffic_providers(spec, road_map, state))
    terminate = np.zeros(NUM_EVENTS, dtype=bool)
    for name in first.events.terminate_on:
        terminate[event_from_name(name)] = True
    events = EventConfig(terminate_on=terminate, not_moving_seconds=first.events.not_moving_seconds,
                         not_moving_distance=first.events.not_moving_distance)  # fmt: skip
    agents = BatchedAgentProvider(vehicles, limits, first.step_length, lane_relative, torch_device)
    sim = BatchedSimulation(
        stack, missions, [agents], episode_providers, dt=first.step_length,
        episode_steps=[s.episode_steps for s in specs], events=events,
        capacity=max(s.vehicle_capacity for s in specs),
        seeds=[check_seed(s, f"seeds[{b}]") for b, s in enumerate(seeds)], signals=signals, episode_map=episode_map,
    )  # fmt: skip
    agents.vehicles = [dataclasses.replace(v, agent_id=aid) for v, aid in zip(vehicles, sim.agent_ids)]
    if batch_traffic:
        from smarts.env.batched.traffic import BatchedBuiltinTraffic

        stage = BatchedBuiltinTraffic(sim)
        if stage.provider:
            sim.add_batch_stage(stage)
    return sim
