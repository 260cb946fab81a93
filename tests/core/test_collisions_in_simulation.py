"""Collision events at simulation level, among many vehicles: every pair of agents and every traffic
row. The kernel tests (test_events.py) check the box geometry; these check that the simulation
tests each agent against every live row and flags exactly the vehicles that touch."""

import itertools

import numpy as np
import pytest

from smarts.core.events import Event
from smarts.core.vehicle_table import Role
from smarts.env import DrivingParallelEnv
from tests.builders import agent, make_spec

N = 8
STRAIGHT = np.array([1.0, 0.0, 0.0])  # 1 m per step at 10 m/s: every vehicle moves alike


@pytest.fixture(scope="module")
def env():
    agents = [agent(offset=10.0 + 20.0 * k) for k in range(N)]
    env = DrivingParallelEnv(make_spec(agents, events={"terminate_on": []}))
    env.reset(seed=0)
    return env


def _line_up(env, x0=10.0):
    """Every agent on the right lane's centre, heading down the road, 20 m apart (no contact)."""
    t, rows = env.sim.table, env.sim.agent_row[:N]
    t.x[rows] = x0 + 20.0 * np.arange(N)
    t.y[rows] = -4.8
    t.heading[rows] = 0.0
    t.speed[rows] = 10.0


def _collided(env) -> set[int]:
    return set(np.flatnonzero(env.sim.agent_events[:N, Event.COLLISION]).tolist())


def test_separated_vehicles_do_not_collide(env):
    _line_up(env)
    env.step({a: STRAIGHT for a in env.agents})
    assert _collided(env) == set()


@pytest.mark.parametrize("i,j", list(itertools.combinations(range(N), 2)))
def test_every_pair_collides_and_only_that_pair(env, i, j):
    _line_up(env)
    t, rows = env.sim.table, env.sim.agent_row
    # j moves to 3 m ahead of i in the same lane: boxes about 4.5 m long overlap by 1.5 m.
    t.x[rows[j]] = t.x[rows[i]] + 3.0
    if j == N - 1:  # and the last one side by side with the overlap lateral instead
        t.x[rows[j]], t.y[rows[j]] = t.x[rows[i]], t.y[rows[i]] + 1.5
    env.step({a: STRAIGHT for a in env.agents})
    assert _collided(env) == {i, j}


def test_an_agent_collides_with_every_traffic_row_it_touches():
    env = DrivingParallelEnv(make_spec(
        [agent(lane=1, offset=5.0)], map_name="straight_2lane",
        traffic={"engine": "builtin", "flows": [{"id": "f", "route": ["main"], "rate": 1800}]},
        events={"terminate_on": []},
    ))  # fmt: skip
    env.reset(seed=0)
    t = env.sim.table
    row = env.sim.agent_row[0]
    checked = 0
    for _ in range(80):
        traffic = [r for r in t.alive_rows if t.role[r] == Role.TRAFFIC and t.x[r] > 20.0]
        if len(traffic) >= 3:
            break
        t.x[row], t.y[row] = 1.0, -1.6  # the agent waits at the start of the left lane
        env.step({"agent_0": np.array([0.0, 0.0, 0.0])})
    assert len(traffic) >= 3, "the flow put too few vehicles on the road to test"
    for target in traffic:
        # The agent put right onto the traffic vehicle, then both drive on for a step.
        t.x[row], t.y[row], t.heading[row], t.speed[row] = t.x[target], t.y[target], t.heading[target], t.speed[target]
        env.step({"agent_0": np.array([t.speed[row] * env.sim.dt, 0.0, 0.0])})
        assert env.sim.agent_events[0, Event.COLLISION], f"no collision with traffic row {target}"
        # Clear of every vehicle again: behind them all, in the other lane.
        t.x[row], t.y[row] = 1.0, -1.6
        env.step({"agent_0": STRAIGHT})
        assert not env.sim.agent_events[0, Event.COLLISION]
        checked += 1
    assert checked == len(traffic)


def test_partial_off_road_sees_each_corner():
    """A parked car 0.9 m inside the right road edge, turned so that one corner sticks about 0.9 m
    over the edge while its centre and other corners stay on; four headings put each of its four
    corners (front/rear, left/right) over the edge in turn."""
    seen = set()
    for heading in (0.45, -0.45, np.pi + 0.45, np.pi - 0.45):
        env = DrivingParallelEnv(make_spec([agent(offset=30.0, speed=0.0)], events={"terminate_on": []}))
        env.reset(seed=0)
        t, row = env.sim.table, env.sim.agent_row[0]
        t.y[row], t.heading[row], t.speed[row] = -6.4 + 0.9, heading, 0.0
        env.step({"agent_0": np.zeros(3)})  # stays where it is
        corners = t.corners(np.array([row]))[0]
        out = corners[:, 1] < -6.4
        assert out.sum() == 1 and corners[out, 1][0] < -6.4 - 0.8, heading  # one corner, clearly over
        ev = env.sim.agent_events[0]
        assert ev[Event.PARTIAL_OFF_ROAD] and not ev[Event.OFF_ROAD], heading
        seen.add(int(np.flatnonzero(out)[0]))
        env.close()
    assert seen == {0, 1, 2, 3}
