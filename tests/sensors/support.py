"""Scenes with hand-placed road users on the straight two-lane road (real netconvert map).

Lane 0 of ``main`` runs east along y = -4.8 and lane 1 along y = -1.6 (3.2 m lanes), so the road
surface spans y = -6.4 .. 0. Tests move rows of the vehicle table to exact poses and build the
observation from there, so every expected value can be worked out by hand.
"""

from __future__ import annotations

import numpy as np

from smarts.env import DrivingParallelEnv
from smarts.sensors.interface import AgentInterface
from tests.builders import agent, make_spec

LANE0_Y = -4.8
LANE1_Y = -1.6
LANE_WIDTH = 3.2
ROAD_RIGHT_EDGE = -6.4
ROAD_LEFT_EDGE = 0.0
CAR_LENGTH, CAR_WIDTH = 4.6, 1.9  # passenger defaults


def scene_env(n_agents: int, interface: AgentInterface, **extra) -> DrivingParallelEnv:
    """``n_agents`` standing agents spread along lane 0, all with ``interface``."""
    agents = [agent(lane=0, offset=20.0 + 10.0 * i, speed=0.0) for i in range(n_agents)]
    env = DrivingParallelEnv(make_spec(agents, **extra), observation=interface)
    env.reset(seed=0)
    return env


def place(env: DrivingParallelEnv, agent_index: int, x: float, y: float, heading: float = 0.0, **columns) -> int:
    """Move an agent's vehicle to a pose (and any other table columns); returns its row."""
    table = env.sim.table
    row = int(env.sim.agent_row[agent_index])
    table.x[row], table.y[row], table.heading[row] = x, y, heading
    for name, value in columns.items():
        getattr(table, name)[row] = value
    env.sim.update_map_state()  # lane, s, t of the new pose, as after a step
    return row


def observe(env: DrivingParallelEnv, agents=(0,)) -> dict[str, np.ndarray]:
    return env.builder.build(env.sim, np.asarray(agents, dtype=np.int64))
