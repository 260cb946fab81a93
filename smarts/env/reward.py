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
    """float64[n] rewards for ``agents`` this step; ``weights`` is a ``RewardSpec``."""
    ev = sim.agent_events[agents]
    reward = weights.progress_weight * sim.route_progress_delta[agents]
    reward -= weights.collision_penalty * ev[:, Event.COLLISION]
    reward -= weights.off_road_penalty * ev[:, Event.OFF_ROAD]
    reward += weights.goal_bonus * ev[:, Event.REACHED_GOAL]
    reward -= weights.step_penalty
    return reward
