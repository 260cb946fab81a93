"""The default reward: metres of progress along the route, penalties for ending events, a goal bonus."""

from __future__ import annotations

import numpy as np

from typing import Callable

from smarts.core.events import Event
from smarts.core.simulation import Simulation

RewardFunction = Callable[[Simulation, np.ndarray], np.ndarray]
"""``reward(sim, agents) -> float64[n]``: this step's reward of each agent index in ``agents``,
called after the step (events and route progress are up to date)."""


def default_rewards(sim: Simulation, agents: np.ndarray, weights) -> np.ndarray:
    """float64[n] rewards for ``agents`` this step; ``weights`` is a ``RewardSpec`` (every agent's)
    or float64[5, n]: each agent's progress weight, collision and off-road penalties, goal bonus
    and step penalty (agents of several scenarios)."""
    if not isinstance(weights, np.ndarray):
        weights = np.array([[weights.progress_weight], [weights.collision_penalty], [weights.off_road_penalty],
                            [weights.goal_bonus], [weights.step_penalty]])  # fmt: skip
    progress, collision, off_road, goal, step = weights
    ev = sim.agent_events[agents]
    reward = progress * sim.route_progress_delta[agents]
    reward -= collision * ev[:, Event.COLLISION]
    reward -= off_road * ev[:, Event.OFF_ROAD]
    reward += goal * ev[:, Event.REACHED_GOAL]
    reward -= step
    return reward
