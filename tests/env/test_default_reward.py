"""The scenario's default reward, term by term: each weight is switched on alone, the event it pays
for is produced in a real simulation, and the reward is checked against the value computed here."""

import numpy as np
import pytest

from smarts.core.events import Event
from smarts.env import DrivingParallelEnv
from tests.builders import agent, make_spec

OFF = {"progress_weight": 0.0, "collision_penalty": 0.0, "off_road_penalty": 0.0, "goal_bonus": 0.0,
       "step_penalty": 0.0}  # fmt: skip
STRAIGHT = np.array([1.0, 0.0, 0.0])  # 1 m forward per step at 10 m/s


def _env(agents, **reward):
    spec = make_spec(agents, reward={**OFF, **reward}, events={"terminate_on": []})
    env = DrivingParallelEnv(spec)
    env.reset(seed=0)
    return env


def test_progress_pays_metres_along_the_route():
    env = _env([agent(offset=10.0)], progress_weight=2.5)
    for _ in range(3):
        reward = env.step({"agent_0": STRAIGHT})[1]["agent_0"]
        # 1 m straight down the lane: 1 m of progress.
        assert reward == pytest.approx(2.5 * 1.0, abs=1e-3)
        assert reward == pytest.approx(2.5 * env.sim.route_progress_delta[0])


def test_step_penalty_is_charged_every_step():
    env = _env([agent(offset=10.0)], step_penalty=0.3)
    rewards = [env.step({"agent_0": STRAIGHT})[1]["agent_0"] for _ in range(4)]
    assert rewards == pytest.approx([-0.3] * 4)


def test_collision_penalty_is_charged_to_both_vehicles_on_the_collision_step():
    env = _env([agent(offset=10.0, speed=10.0), agent(offset=16.0, speed=10.0)], collision_penalty=4.0)
    for _ in range(10):
        # agent_0 speeds up into agent_1, which slows down.
        rewards = env.step({"agent_0": np.array([1.4, 0.0, 0.0]), "agent_1": np.array([0.6, 0.0, 0.0])})[1]
        if env.sim.agent_events[:, Event.COLLISION].any():
            break
    assert env.sim.agent_events[:, Event.COLLISION].all()
    assert rewards == {"agent_0": pytest.approx(-4.0), "agent_1": pytest.approx(-4.0)}
    # The steps before the collision were free.
    env = _env([agent(offset=10.0, speed=10.0), agent(offset=40.0, speed=10.0)], collision_penalty=4.0)
    assert env.step({"agent_0": STRAIGHT, "agent_1": STRAIGHT})[1] == {"agent_0": 0.0, "agent_1": 0.0}


def test_off_road_penalty_is_charged_when_the_vehicle_leaves_the_road():
    env = _env([agent(offset=10.0)], off_road_penalty=6.0)
    assert env.step({"agent_0": STRAIGHT})[1]["agent_0"] == 0.0
    row = env.sim.agent_row[0]
    env.sim.table.y[row] += 30.0  # far beside the two-lane road
    reward = env.step({"agent_0": STRAIGHT})[1]["agent_0"]
    assert env.sim.agent_events[0, Event.OFF_ROAD]
    assert reward == pytest.approx(-6.0)


def test_goal_bonus_is_paid_on_the_step_the_goal_is_reached():
    env = _env([agent(offset=80.0, goal={"road": "main", "offset": 85.0})], goal_bonus=3.0)
    rewards = []
    for _ in range(20):
        rewards.append(env.step({"agent_0": STRAIGHT})[1]["agent_0"])
        if env.sim.agent_events[0, Event.REACHED_GOAL]:
            break
    assert env.sim.agent_events[0, Event.REACHED_GOAL]
    assert rewards[-1] == pytest.approx(3.0) and all(r == 0.0 for r in rewards[:-1])


def test_terms_add_up():
    env = _env([agent(offset=10.0)], progress_weight=1.0, step_penalty=0.5, off_road_penalty=2.0)
    env.sim.table.y[env.sim.agent_row[0]] += 30.0
    reward = env.step({"agent_0": STRAIGHT})[1]["agent_0"]
    assert reward == pytest.approx(env.sim.route_progress_delta[0] - 0.5 - 2.0)
