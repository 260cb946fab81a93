"""The agent provider: owns the agents' vehicles and turns their actions into motion.

Agents are grouped by action space once at construction, so a step runs one vectorised controller
call per group (pose limiting, lane control) and one pybullet step for all Continuous agents.
Every group's actions (and lane-relative commands) are checked on their stacked arrays before any
group moves (``check_actions``, called by ``Simulation.step`` before its clock advances), so a
refused step leaves vehicles, controllers and the physics exactly as they were.
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
    REAL_KINDS,
    ActionSpaceType,
    action_components,
    action_label,
    action_problem,
    lane_command,
)
from smarts.dynamics.bicycle import wheelbase_for_length
from smarts.dynamics.lane_control import lane_control_step
from smarts.dynamics.lane_relative import LaneRelativeController, LaneRelativeParams
from smarts.dynamics.limits import ReachLimits
from smarts.dynamics.pose_control import (
    all_finite,
    apply_relative_pose,
    apply_target_pose,
    limit_params,
    move_to_poses,
)

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
    """The batch provider of every agent of every episode (``smarts.core.simulation``).

    Actions arrive as a dict by agent id or as one array ``[agents, k]`` (each action-space group
    reads its first columns); either way every group is checked and stacked before any moves.
    Continuous agents drive pybullet cars, one physics world per episode (so an episode's
    physics is the same alone or in a batch, and cars of different episodes never touch).
    ``device``: a torch device for the pose groups (``smarts.dynamics.pose_control_torch``);
    None runs the compiled numpy kernels."""

    name = "agents"

    def __init__(
        self,
        vehicles: list[AgentVehicle],
        limits: ReachLimits,
        dt: float,
        lane_relative: LaneRelativeParams | None = None,
        device=None,
    ):
        self.vehicles = vehicles
        self.limits = limits
        self.dt = dt
        self.device = device
        self.groups: dict[ActionSpaceType, np.ndarray] = {}
        for kind in ActionSpaceType:
            members = [i for i, v in enumerate(vehicles) if v.action_space is kind]
            if members:
                self.groups[kind] = np.array(members, dtype=np.int64)
        for v in vehicles:
            if v.controller == "lane_relative" and v.action_space is ActionSpaceType.LANE:
                raise ValueError(f"{v.agent_id}: the lane_relative controller cannot drive the lane action space")
        self.commanded = np.array([v.controller == "lane_relative" for v in vehicles], dtype=bool)
        self.lane_relative = LaneRelativeController(len(vehicles), lane_relative) if self.commanded.any() else None
        self.physical = np.array([v.action_space is ActionSpaceType.CONTINUOUS for v in vehicles], dtype=bool)
        self.worlds: dict[int, object] = {}  # episode -> pybullet PhysicsWorld (Continuous agents only)
        self.handles = np.full(len(vehicles), -1, dtype=np.int64)
        self.mass = np.zeros(len(vehicles))  # whole-car mass of physics cars, kg
        self.lane_offset = np.zeros(len(vehicles), dtype=np.int64)  # lane agents: 0 route, +1 left, -1 right
        self.wheelbase = np.array([wheelbase_for_length(v.length) for v in vehicles])
        self.width = max(len(action_components(v.action_space, v.controller)) for v in vehicles) if vehicles else 0
        """Columns of an action array: the widest action of any agent."""
        self._taking: int | None = None  # agent whose take-over is in progress
        self._group_commanded = {kind: bool(self.commanded[m].any()) for kind, m in self.groups.items()}
        self._planned: tuple[object, list] | None = None  # (actions, plans) of the last full check
        self._layout_of: tuple[np.ndarray, list] | None = None  # (active agents, their group layout)
        self._limit_params = limit_params(limits)  # the pose kernels' form of ``limits``

    # ------------------------------------------------------------------ episode
    def reset_episode(self, sim: Simulation, b: int, agents: np.ndarray) -> None:
        """Put episode ``b``'s agents at their starts (in agent order, the first rows of its
        block) and clear their controller state; take-overs wait for ``start_episode``."""
        self._planned = None
        if self.physical[agents].any():
            world = self.worlds.get(b)
            if world is None:
                from smarts.dynamics.pybullet_chassis import PhysicsWorld  # loads pybullet

                self.worlds[b] = PhysicsWorld(dt=self.dt)
            else:
                world.reset()
        self.handles[agents] = -1
        self.lane_offset[agents] = 0
        if self.lane_relative is not None:
            self.lane_relative.reset_agents(sim, agents)
        view = sim.views[b]
        for a in agents.tolist():
            vehicle, mission = self.vehicles[a], sim.missions[a]
            if vehicle.take_over is not None:
                continue  # taken from traffic in start_episode, once traffic has created it
            x, y = mission.start_xy
            row = view.table.add(
                sim.local_agent_ids[a], owner=self.provider_id, role=vehicle.role, x=float(x), y=float(y),
                heading=mission.start_heading, speed=mission.start_speed, vtype=vehicle.vtype,
                length=vehicle.length, width=vehicle.width, height=vehicle.height,
            )  # fmt: skip
            sim.agent_row[a] = view.base + row
            self._add_physics(a, sim, view.base + row)

    def start_episode(self, sim: Simulation, b: int, agents: np.ndarray) -> None:
        """Take over the traffic vehicles named by ``take_over`` missions (they exist by now)."""
        view = sim.views[b]
        for a in agents.tolist():
            vehicle = self.vehicles[a]
            if vehicle.take_over is None:
                continue
            row = view.table.row_of.get(vehicle.take_over)
            if row is None:
                raise RuntimeError(
                    f"{sim.local_agent_ids[a]}: mission.start.take_over: traffic created no vehicle "
                    f"{vehicle.take_over!r} at reset (a trip departing at 0 s is needed)"
                )
            self._taking = a
            sim.hand_over(np.array([view.base + row]), self, vehicle.role)

    def can_accept(self, sim: Simulation, rows: np.ndarray) -> np.ndarray:
        return np.full(len(rows), self._taking is not None)

    def accept(self, sim: Simulation, rows: np.ndarray) -> None:
        """A taken-over vehicle keeps its pose, speed and size; it becomes the agent's."""
        (row,) = np.asarray(rows).tolist()
        agent, self._taking = self._taking, None
        sim.agent_row[agent] = row
        self._add_physics(agent, sim, row)

    def _add_physics(self, agent: int, sim: Simulation, row: int) -> None:
        if not self.physical[agent]:
            return
        vehicle = self.vehicles[agent]
        world = self.worlds[int(sim.agent_episode[agent])]
        t = sim.table
        self.handles[agent] = world.add_vehicle(
            float(t.x[row]), float(t.y[row]), float(t.heading[row]), float(t.speed[row]),
            float(t.length[row]), float(t.width[row]), float(t.height[row]), vehicle.mass,
        )  # fmt: skip
        self.mass[agent] = world.vehicle_mass([self.handles[agent]])[0]
        self.wheelbase[agent] = world.wheelbase([self.handles[agent]])[0]

    def release(self, sim: Simulation, rows: np.ndarray) -> None:
        if not self.worlds:
            return
        for row in np.asarray(rows).tolist():
            for agent in np.flatnonzero(sim.agent_row == row).tolist():
                if self.handles[agent] >= 0:
                    self.worlds[int(sim.agent_episode[agent])].remove_vehicle(int(self.handles[agent]))
                    self.handles[agent] = -1

    def close(self) -> None:
        for world in self.worlds.values():
            world.close()
        self.worlds = {}

    # ------------------------------------------------------------------ step
    def check_actions(self, sim: Simulation, actions, agents: np.ndarray | None = None) -> None:
        """Check the actions of every active agent (or of ``agents``, agent indices) in every group
        and controller at once; raise one ``ActionError`` naming every bad agent and what was
        expected. Nothing changes; a full check keeps the stacked arrays for the ``step`` that
        follows it (``Simulation.step`` checks, then steps)."""
        plans = self._plan(sim, actions, agents)
        if agents is None:
            self._planned = (actions, plans)

    def _plan(self, sim: Simulation, actions, agents: np.ndarray | None) -> list:
        """Per action-space group: ``(kind, members, commanded, direct, commands)``, the float64
        arrays of its direct actions and lane-relative commands (None when it has none)."""
        if isinstance(actions, np.ndarray):
            return self._plan_array(sim, actions, agents)
        plans = []
        problems: list[str] = []
        bad: list[str] = []
        for kind, members, commanded, parts in self._layout(sim, agents):
            arrays = []
            for part in parts:
                if part is None:
                    arrays.append(None)
                    continue
                controller, group_ids, width = part
                arr = _stack(actions, group_ids, width)
                if arr is None:  # something is wrong, or unusual (tensors): look at each agent
                    found = len(problems)
                    for a in group_ids:
                        problem = (
                            action_problem(kind, actions[a], a, controller)
                            if a in actions
                            else f"{a}: no {action_label(kind, controller)} action given this step"
                        )
                        if problem is not None:
                            problems.append(problem)
                            bad.append(a)
                    if len(problems) == found:  # each one is fine on its own
                        arr = np.stack([np.asarray(actions[a], dtype=np.float64) for a in group_ids])
                arrays.append(arr)
            plans.append((kind, members, commanded, *arrays))
        if problems:
            raise ActionError("; ".join(problems), bad)
        return plans

    def _layout(self, sim: Simulation, agents: np.ndarray | None) -> list:
        """Per action-space group with active agents (among ``agents``, None: all): ``(kind,
        members, commanded, parts)``, ``parts`` the direct and lane-relative ``(controller, ids,
        action width)``
        (None where none). Kept while the simulation's active agents stay the same (``step``
        then does no per-group array work to find them)."""
        active = sim.active_agents
        if agents is None and self._layout_of is not None and self._layout_of[0] is active:
            return self._layout_of[1]
        ids = sim.agent_ids
        layout = []
        for kind, members in self.groups.items():
            members = members[sim.agent_active[members]]
            if agents is not None:
                members = members[np.isin(members, agents)]
            if members.size == 0:
                continue
            commanded = self.commanded[members] if self._group_commanded[kind] else None
            parts = []
            for controller in ("direct", "lane_relative"):
                if commanded is None:
                    chosen = members if controller == "direct" else None
                else:
                    chosen = members[~commanded if controller == "direct" else commanded]
                if chosen is None or chosen.size == 0:
                    parts.append(None)
                else:
                    width = len(action_components(kind, controller))
                    parts.append((controller, [ids[i] for i in chosen.tolist()], width))
            layout.append((kind, members, commanded, parts))
        if agents is None:
            self._layout_of = (active, layout)
        return layout

    def _plan_array(self, sim: Simulation, actions: np.ndarray, agents: np.ndarray | None) -> list:
        """``_plan`` of an array: row ``a`` agent ``a``'s action, each group reads its first
        columns (``width`` columns in all: the widest action)."""
        n = len(sim.agent_ids)
        if actions.ndim != 2 or actions.shape[0] != n or actions.shape[1] < self.width:
            raise ActionError(
                f"expected an action array of shape ({n}, {self.width}) (agents, action components), got {actions.shape}",
                [],
            )
        if actions.dtype.kind not in REAL_KINDS:
            raise ActionError(f"expected real-number actions, got dtype {actions.dtype}", [])
        plans = []
        bad: list[str] = []
        for kind, members, commanded, layout in self._layout(sim, agents):
            parts = []
            for part, direct in zip(layout, (True, False)):
                if part is None:
                    parts.append(None)
                    continue
                chosen = members if commanded is None else members[~commanded if direct else commanded]
                arr = np.asarray(actions[chosen, : part[2]], dtype=np.float64)
                finite = np.isfinite(arr).all(axis=1)
                if not finite.all():
                    bad += [sim.agent_ids[a] for a in chosen[~finite].tolist()]
                parts.append(arr)
            plans.append((kind, members, commanded, *parts))
        if bad:
            raise ActionError(f"actions of agents {bad} are not finite numbers", bad)
        return plans

    def step(self, sim: Simulation, dt: float) -> None:
        planned, self._planned = self._planned, None
        if planned is not None and planned[0] is sim.actions:
            plans = planned[1]
        else:  # stepped without a check first: check now, still before anything moves
            plans = self._plan(sim, sim.actions, None)
        for kind, members, commanded, direct, commands in plans:
            rows = sim.agent_row[members]
            if commanded is None:
                actions = direct
            else:
                actions = np.empty((len(members), len(ACTION_COMPONENTS[kind])))
                if direct is not None:
                    actions[~commanded] = direct
                if commands is not None:  # lane-relative commands -> this space's own actions
                    actions[commanded] = self._from_commands(
                        kind, sim, members[commanded], rows[commanded], commands, dt
                    )
            self._drive(kind, sim, members, rows, actions, dt, checked=commanded is None)

    def _from_commands(self, kind, sim, members, rows, commands, dt) -> np.ndarray:
        ctl = self.lane_relative
        if kind is ActionSpaceType.RELATIVE_TARGET_POSE:
            return ctl.relative_pose_actions(sim, members, rows, commands, dt)
        if kind is ActionSpaceType.TARGET_POSE:
            return ctl.target_pose_actions(sim, members, rows, commands, dt)
        world = next(iter(self.worlds.values()))  # the car model's constants (every world has the same)
        return ctl.continuous_actions(
            sim, members, rows, commands, dt, world, self.mass[members], self.wheelbase[members]
        )

    def _drive(self, kind, sim, members, rows, actions, dt, checked: bool = False) -> None:
        """Move ``rows`` by ``actions`` of ``kind``; ``checked``: the actions are the plan's
        own float64 arrays, already checked (the pose kernel then runs without a second guard)."""
        if kind in (ActionSpaceType.RELATIVE_TARGET_POSE, ActionSpaceType.TARGET_POSE) and self.device is not None:
            from smarts.dynamics.pose_control_torch import apply_pose_torch

            apply_pose_torch(
                sim.table, rows, actions, kind is ActionSpaceType.TARGET_POSE, dt, self.limits, self.device
            )
        elif checked and kind in (ActionSpaceType.RELATIVE_TARGET_POSE, ActionSpaceType.TARGET_POSE):
            move_to_poses(sim.table, rows, actions, kind is ActionSpaceType.TARGET_POSE, dt, self._limit_params)
        elif kind is ActionSpaceType.RELATIVE_TARGET_POSE:
            apply_relative_pose(sim.table, rows, actions, dt, self.limits)
        elif kind is ActionSpaceType.TARGET_POSE:
            apply_target_pose(sim.table, rows, actions, dt, self.limits)
        elif kind is ActionSpaceType.CONTINUOUS:
            from smarts.dynamics.pybullet_chassis import apply_continuous

            episode = sim.agent_episode[members]
            for b in np.unique(episode).tolist():  # one physics world per episode
                mine = episode == b
                apply_continuous(self.worlds[b], sim.table, rows[mine], self.handles[members[mine]], actions[mine], dt)
        else:
            self._lane_step(sim, members, rows, actions, dt)

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


def _stack(actions: dict, ids: list[str], width: int) -> np.ndarray | None:
    """The ``[n, width]`` float64 array of the agents' actions, or None when any is missing, not
    real numbers, wrongly shaped or not finite (checked on the stacked array: no work per agent)."""
    try:
        arr = np.array([actions[a] for a in ids])
    except (KeyError, TypeError, ValueError):
        return None
    if arr.dtype.kind not in REAL_KINDS or arr.shape != (len(ids), width):
        return None
    arr = arr.astype(np.float64, copy=False)
    if not all_finite(arr):
        return None
    return arr
