"""The default reward: metres of progress along the route, penalties for ending events, a goal bonus."""

from __future__ import annotations

from typing import Callable

import numpy as np

from smarts.compiled import njit
from smarts.core.events import Event
from smarts.core.simulation import Simulation

RewardFunction = Callable[[Simulation, np.ndarray], np.ndarray]
"""``reward(sim, agents) -> float64[n]``: this step's reward of each agent index in ``agents``,
called after the step (events and route progress are up to date)."""

REWARD_WEIGHTS = ("progress_weight", "collision_penalty", "off_road_penalty", "goal_bonus", "step_penalty")
"""The default reward's weights, in the order ``default_rewards`` takes them."""


def reward_weights(specs) -> np.ndarray:
    """float64[5, n]: the ``REWARD_WEIGHTS`` of each of ``specs`` (``RewardSpec``s)."""
    return np.array([[getattr(r, n) for r in specs] for n in REWARD_WEIGHTS], dtype=np.float64).reshape(5, len(specs))


def default_rewards(sim: Simulation, agents: np.ndarray, weights) -> np.ndarray:
    """float64[n] rewards for ``agents`` this step. ``weights``: a ``RewardSpec`` (every agent's),
    or float64[5, n] (``reward_weights``: each agent's, in the order of ``agents``) or [5, 1]
    (every agent's). One compiled pass: progress * weight - collision - off road + goal - step."""
    if not isinstance(weights, np.ndarray):
        weights = reward_weights([weights])
    agents = np.asarray(agents, dtype=np.int64)
    out = np.empty(len(agents))
    _rewards(sim.agent_events, sim.route_progress_delta, agents, weights, out)
    return out


@njit(nogil=True)
def _rewards(events, delta, agents, weights, out):  # pragma: no cover - compiled
    per_agent = weights.shape[1] > 1
    for i in range(agents.shape[0]):
        a = agents[i]
        w = i if per_agent else 0
        r = weights[0, w] * delta[a]
        r -= weights[1, w] * events[a, _COLLISION]
        r -= weights[2, w] * events[a, _OFF_ROAD]
        r += weights[3, w] * events[a, _GOAL]
        r -= weights[4, w]
        out[i] = r


_COLLISION, _OFF_ROAD, _GOAL = int(Event.COLLISION), int(Event.OFF_ROAD), int(Event.REACHED_GOAL)
