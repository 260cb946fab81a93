"""Per-agent memory for stateful planners behind the zoo's batched ``act``.

A zoo policy receives ``{key: [n, ...]}`` for the n live agents, without agent ids; rows keep the
order of the agents but drop out as agents finish, and a policy may be reused across episodes (as
a social agent). Each agent's state therefore records what its next observation should look like
(speed and route distance left after its last action); :func:`align` matches the rows of a call to
the states of the previous call in order, and a state whose expectation is far off is started
afresh (a new episode, a teleport).
"""

from __future__ import annotations

from typing import Any

import numpy as np

from agents.obs_columns import Ego, Goal
from agents.planners.frames import Odometry

RELATIVE_TARGET_POSE = "relative_target_pose"
SPEED_CHANGE = (10.0, 5.0)
"""(braking, accelerating) m/s^2 at most in one step, a little above the vehicle limits (9, 4)."""


class AgentState:
    """What every planner keeps per agent: odometry, the last step and the next-observation guess."""

    def __init__(self) -> None:
        self.odometry = Odometry()
        self.steps = 0
        self.last_action: np.ndarray | None = None
        self.expect_speed = 0.0
        self.expect_route = 0.0
        self.speed = 0.0

    def mismatch(self, ego: np.ndarray, goal: np.ndarray) -> float:
        """How far this observation is from what the last action should have produced (0: as
        expected; above 1: not this agent's next step)."""
        if self.last_action is None:
            return 0.0
        speed_gap = abs(float(ego[Ego.SPEED]) - self.expect_speed) / 2.0
        route_gap = abs(float(goal[Goal.ROUTE_LEFT]) - self.expect_route) / 8.0 if goal[Goal.HAS_GOAL] > 0 else 0.0
        return speed_gap + route_gap

    def observe(self, ego: np.ndarray) -> None:
        """Integrate the executed last step into the odometry (its length scaled to the distance
        the observed speed allows when the limits cut the request short)."""
        self.speed = max(float(ego[Ego.SPEED]), 0.0)
        if self.last_action is None:
            return
        step = self.last_action.astype(np.float64).copy()
        asked = float(np.hypot(step[0], step[1]))
        done = max(float(ego[Ego.SPEED]), 0.0) * 0.1
        if asked > 1e-6 and asked > 1.1 * done + 0.05:
            step[:2] *= done / asked
        self.odometry.advance(step)

    def acted(self, action: np.ndarray, goal: np.ndarray, dt: float) -> None:
        self.last_action = np.asarray(action, dtype=np.float64)
        travel = float(np.hypot(action[0], action[1]))
        # the speed the step asks for, as far as the vehicle's limits let it change in one step: a
        # stop commanded at speed is a brake, and the next observation still moves
        self.expect_speed = float(
            np.clip(travel / dt, self.speed - SPEED_CHANGE[0] * dt, self.speed + SPEED_CHANGE[1] * dt)
        )
        self.expect_route = float(goal[Goal.ROUTE_LEFT]) - travel
        self.steps += 1


def align(states: list[AgentState], obs: dict[str, np.ndarray]) -> list[AgentState | None]:
    """States for the rows of ``obs`` (None: start afresh): the order-keeping assignment of rows to
    the previous call's states with the least total mismatch; more rows than states starts all."""
    n, m = len(obs["ego"]), len(states)
    if m == 0 or n > m:
        return [None] * n
    cost = np.array([[s.mismatch(obs["ego"][i], obs["goal"][i]) for s in states] for i in range(n)])
    if n == m:
        picked = list(range(m))
    else:  # choose n of m in order: dynamic programming over (row, state)
        inf = np.inf
        best = np.full((n + 1, m + 1), inf)
        best[0, :] = 0.0
        for i in range(1, n + 1):
            for j in range(i, m + 1):
                best[i, j] = min(best[i, j - 1], best[i - 1, j - 1] + cost[i - 1, j - 1])
        picked, i, j = [], n, m
        while i > 0:
            if best[i, j] == best[i, j - 1] and j > i:
                j -= 1
            else:
                picked.append(j - 1)
                i, j = i - 1, j - 1
        picked.reverse()
    return [states[j] if cost[i, j] <= 1.0 else None for i, j in enumerate(picked)]


class StatefulPlanner:
    """Base of the planners: per-agent states kept across calls, ``decide`` per agent row."""

    action_space = RELATIVE_TARGET_POSE
    dt = 0.1
    batching = "instances"  # per-agent memory across calls: one instance per benchmark episode

    def __init__(self) -> None:
        self._states: list[AgentState] = []

    def new_state(self) -> AgentState:
        return AgentState()

    def decide(self, state: Any, row: dict[str, np.ndarray]) -> np.ndarray:
        raise NotImplementedError

    def act(self, obs: dict[str, np.ndarray]) -> np.ndarray:
        """Batched actions [n, 3] (RelativeTargetPose) for the n rows of ``obs``."""
        matched = align(self._states, obs)
        states: list[AgentState] = []
        out = np.zeros((len(obs["ego"]), 3), dtype=np.float32)
        for i, state in enumerate(matched):
            row = {k: v[i] for k, v in obs.items()}
            if state is None:
                state = self.new_state()
            state.observe(row["ego"])
            action = np.asarray(self.decide(state, row), dtype=np.float64)
            state.acted(action, row["goal"], self.dt)
            out[i] = action
            states.append(state)
        self._states = states
        return out

    def seed(self, seed: int) -> None:
        """Deterministic planners: nothing to seed; a new episode starts from empty memory."""
        self._states = []
