"""The agent provider: owns the agents' vehicles and turns their actions into motion.

Agents are grouped by action space once at construction, so a step runs one vectorised controller
call per group (pose limiting, lane control) and one pybullet step for all Continuous agents.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from smarts.core.errors import ActionError
from smarts.core.provider import ProviderBase
from smarts.core.simulation import Simulation
from smarts.core.vehicle_table import Role, VehicleType
from smarts.dynamics.action_spaces import (
    ACTION_COMPONENTS,
    LANE_RELATIVE_COMPONENTS,
    ActionSpaceType,
    check_actions,
    lane_command,
)
from smarts.dynamics.bicycle import wheelbase_for_length
from smarts.dynamics.lane_control import lane_control_step
from smarts.dynamics.lane_relative import LaneRelativeController, LaneRelativeParams
from smarts.dynamics.limits import ReachLimits
from smarts.dynamics.pose_control import apply_relative_pose, apply_target_pose

LANE_LOOKAHEAD_TIME = 1.0  # s of travel to the pure-pursuit point of the lane controller
LANE_MIN_LOOKAHEAD = 6.0  # m


@dataclass(frozen=True)
class AgentVehicle:
    """What the provider needs to know about one agent's vehicle."""

    agent_id: str
    action_space: ActionSpaceType
    vtype: VehicleType
    length: float
    width: float
    height: float
    mass: float
    role: Role = Role.AGENT  # SOCIAL_AGENT for agents driven by a zoo policy
    take_over: str | None = None  # id of a traffic vehicle this agent takes over at reset
    controller: str = "direct"  # or "lane_relative": commands turned into this space's actions


class AgentProvider(ProviderBase):
    name = "agents"

    def __init__(
        self,
        vehicles: list[AgentVehicle],
        limits: ReachLimits,
        dt: float,
        lane_relative: LaneRelativeParams | None = None,
    ):
        self.vehicles = vehicles
        self.limits = limits
        self.dt = dt
        self.groups: dict[ActionSpaceType, np.ndarray] = {}
        for kind in ActionSpaceType:
            members = [i for i, v in enumerate(vehicles) if v.action_space is kind]
            if members:
                self.groups[kind] = np.array(members, dtype=np.int64)
        for v in vehicles:
            if v.controller == "lane_relative" and v.action_space is ActionSpaceType.LANE:
                raise ValueError(f"{v.agent_id}: the lane_relative controller cannot drive the lane action space")
        self.commanded = np.array([v.controller == "lane_relative" for v in vehicles], dtype=bool)
        self.lane_relative = (
            LaneRelativeController(len(vehicles), lane_relative) if self.commanded.any() else None
        )
        self.world = None  # a pybullet PhysicsWorld, created only when an agent drives Continuous
        self.handles = np.full(len(vehicles), -1, dtype=np.int64)
        self.lane_offset = np.zeros(len(vehicles), dtype=np.int64)  # lane agents: 0 route, +1 left, -1 right
        self.wheelbase = np.array([wheelbase_for_length(v.length) for v in vehicles])
        self._taking: str | None = None  # agent whose take-over is in progress

    # ------------------------------------------------------------------ episode
    def reset(self, sim: Simulation) -> None:
        if ActionSpaceType.CONTINUOUS in self.groups:
            if self.world is None:
                from smarts.dynamics.pybullet_chassis import PhysicsWorld  # loads pybullet

                self.world = PhysicsWorld(dt=self.dt)
            else:
                self.world.reset()
        self.handles[:] = -1
        self.lane_offset[:] = 0
        if self.lane_relative is not None:
            self.lane_relative.reset(sim)
        for i, (vehicle, mission) in enumerate(zip(self.vehicles, sim.missions)):
            if vehicle.take_over is not None:
                continue  # taken from traffic in start(), once traffic has created it
            x, y = mission.start_xy
            row = sim.table.add(
                vehicle.agent_id,
                owner=self.provider_id,
                role=vehicle.role,
                x=float(x),
                y=float(y),
                heading=mission.start_heading,
                speed=mission.start_speed,
                vtype=vehicle.vtype,
                length=vehicle.length,
                width=vehicle.width,
                height=vehicle.height,
            )
            sim.register_agent_vehicle(vehicle.agent_id, row)
            self._add_physics(i, sim, row)

    def start(self, sim: Simulation) -> None:
        """Take over the traffic vehicles named by ``take_over`` missions (they exist by now)."""
        for vehicle in self.vehicles:
            if vehicle.take_over is None:
                continue
            row = sim.table.row_of.get(vehicle.take_over)
            if row is None:
                raise RuntimeError(
                    f"{vehicle.agent_id}: mission.start.take_over: traffic created no vehicle "
                    f"{vehicle.take_over!r} at reset (a trip departing at 0 s is needed)"
                )
            self._taking = vehicle.agent_id
            sim.hand_over(np.array([row]), self, vehicle.role)

    def can_accept(self, sim: Simulation, rows: np.ndarray) -> np.ndarray:
        return np.full(len(rows), self._taking is not None)

    def accept(self, sim: Simulation, rows: np.ndarray) -> None:
        """A taken-over vehicle keeps its pose, speed and size; it becomes the agent's."""
        (row,) = np.asarray(rows).tolist()
        agent = sim.agent_index[self._taking]
        self._taking = None
        sim.register_agent_vehicle(sim.agent_ids[agent], row)
        self._add_physics(agent, sim, row)

    def _add_physics(self, agent: int, sim: Simulation, row: int) -> None:
        vehicle = self.vehicles[agent]
        if vehicle.action_space is not ActionSpaceType.CONTINUOUS:
            return
        t = sim.table
        self.handles[agent] = self.world.add_vehicle(
            float(t.x[row]), float(t.y[row]), float(t.heading[row]), float(t.speed[row]),
            float(t.length[row]), float(t.width[row]), float(t.height[row]), vehicle.mass,
        )

    def release(self, sim: Simulation, rows: np.ndarray) -> None:
        if self.world is None:
            return
        for row in np.asarray(rows).tolist():
            for agent in np.flatnonzero(sim.agent_row == row).tolist():
                if self.handles[agent] >= 0:
                    self.world.remove_vehicle(int(self.handles[agent]))
                    self.handles[agent] = -1

    def close(self) -> None:
        if self.world is not None:
            self.world.close()
            self.world = None

    # ------------------------------------------------------------------ step
    def step(self, sim: Simulation, dt: float) -> None:
        # Every action is checked before anything moves: a bad one leaves all vehicles as they were.
        plans = []
        for kind, members in self.groups.items():
            members = members[sim.agent_active[members]]
            if members.size == 0:
                continue
            commanded = self.commanded[members]
            parts = []
            for mask, controller in ((~commanded, "direct"), (commanded, "lane_relative")):
                ids = [sim.agent_ids[i] for i in members[mask]]
                parts.append(self._gather(kind, sim.actions, ids, controller) if ids else None)
            plans.append((kind, members, commanded, *parts))
        for kind, members, commanded, direct, commands in plans:
            rows = sim.agent_row[members]
            actions = np.empty((len(members), len(ACTION_COMPONENTS[kind])))
            if direct is not None:
                actions[~commanded] = direct
            if commands is not None:  # lane-relative commands -> this space's own actions
                actions[commanded] = self._from_commands(
                    kind, sim, members[commanded], rows[commanded], commands, dt
                )
            self._drive(kind, sim, members, rows, actions, dt)

    def _from_commands(self, kind, sim, members, rows, commands, dt) -> np.ndarray:
        ctl = self.lane_relative
        if kind is ActionSpaceType.RELATIVE_TARGET_POSE:
            return ctl.relative_pose_actions(sim, members, rows, commands, dt)
        if kind is ActionSpaceType.TARGET_POSE:
            return ctl.target_pose_actions(sim, members, rows, commands, dt)
        return ctl.continuous_actions(sim, members, rows, commands, dt, self.world, self.handles[members])

    def _drive(self, kind, sim, members, rows, actions, dt) -> None:
        if kind is ActionSpaceType.RELATIVE_TARGET_POSE:
            apply_relative_pose(sim.table, rows, actions, dt, self.limits)
        elif kind is ActionSpaceType.TARGET_POSE:
            apply_target_pose(sim.table, rows, actions, dt, self.limits)
        elif kind is ActionSpaceType.CONTINUOUS:
            from smarts.dynamics.pybullet_chassis import apply_continuous

            apply_continuous(self.world, sim.table, rows, self.handles[members], actions, dt)
        else:
            self._lane_step(sim, members, rows, actions, dt)

    @staticmethod
    def _gather(kind: ActionSpaceType, actions: dict, ids: list[str], controller: str = "direct") -> np.ndarray:
        """One float64 array of the group's actions; malformed ones raise ``ActionError`` by agent."""
        width = len(ACTION_COMPONENTS[kind]) if controller == "direct" else len(LANE_RELATIVE_COMPONENTS)
        try:
            arr = np.array([actions[a] for a in ids], dtype=np.float64)
        except (KeyError, TypeError, ValueError):
            arr = None
        if arr is None or arr.ndim != 2 or arr.shape[1] != width or not np.isfinite(arr).all():
            for a in ids:  # find the culprit(s) to name them
                if a not in actions:
                    raise ActionError(f"{a}: no action given this step", [a])
                check_actions(kind, np.atleast_1d(np.asarray(actions[a], dtype=object))[None], [a], controller)
            check_actions(kind, arr, ids, controller)
        return arr

    def _lane_step(self, sim: Simulation, members, rows, actions, dt) -> None:
        """Follow the route path or the path one lane left/right of it (see ``MissionArrays``)."""
        target_speed, change = lane_command(actions, self.limits)
        ma = sim.mission_arrays
        offset = np.clip(self.lane_offset[members] + change, -1, 1)
        path = np.where(offset > 0, 1, np.where(offset < 0, 2, 0))
        ahead = np.maximum(sim.table.speed[rows] * LANE_LOOKAHEAD_TIME, LANE_MIN_LOOKAHEAD)
        idx = np.minimum(sim.route_index[members] + np.ceil(ahead).astype(np.int64), ma.path_len[members] - 1)
        feasible = ma.path_valid[members, idx, path]
        kept = self.lane_offset[members]
        kept_path = np.where(kept > 0, 1, np.where(kept < 0, 2, 0))
        kept = np.where(ma.path_valid[members, idx, kept_path], kept, 0)  # that lane ended: route lane
        offset = np.where(feasible, offset, kept)
        path = np.where(offset > 0, 1, np.where(offset < 0, 2, 0))
        self.lane_offset[members] = offset
        target = ma.paths[members, idx, path, :2]
        lane_control_step(sim.table, rows, target_speed, target, dt, self.limits, self.wheelbase[members])
