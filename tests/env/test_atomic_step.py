"""A refused step changes nothing: every agent's action is checked before anything moves.

Agents in different action spaces and controllers share one scenario with traffic; a bad action of
any of them raises an error naming it, and the env then goes on exactly like a copy that never saw
the bad step (vehicles, pybullet cars, lane-relative controller state, traffic, clock, step count,
observations, rewards), bit for bit.
"""

import numpy as np
import pytest

from smarts.core.errors import ActionError
from smarts.env import DrivingParallelEnv
from tests.builders import agent, make_spec

AGENTS = [
    agent(lane=0, offset=10.0, speed=8.0),  # relative_target_pose
    agent(lane=1, offset=20.0, speed=8.0, action_space="continuous"),
    agent(lane=2, offset=30.0, speed=8.0, action_space="continuous", controller="lane_relative"),
    agent(lane=0, offset=45.0, speed=8.0, action_space="target_pose", controller="lane_relative"),
    agent(lane=1, offset=60.0, speed=8.0, action_space="lane"),
]


def _spec():
    return make_spec(
        AGENTS,
        map_name="straight_3lane",
        traffic={"engine": "builtin", "flows": [{"id": "f", "route": ["main"], "rate": 3600, "depart_lane": "random"}]},
        episode_steps=200,
    )


def _actions(env, k):
    """Valid actions of step ``k`` for every live agent (they differ from step to step)."""
    sim = env.sim
    out = {}
    for a in env.agents:
        i = sim.agent_index[a]
        row = sim.agent_row[i]
        kind = env.scenario.agents[i].action_space
        if env.scenario.agents[i].controller == "lane_relative":
            out[a] = np.array([0.1 * np.sin(k), 0.0], dtype=np.float32)
        elif kind == "relative_target_pose":
            out[a] = np.array([0.8 + 0.01 * k, 0.0, 0.001 * k])
        elif kind == "continuous":
            out[a] = np.array([0.3, 0.0, 0.02 * np.cos(k)], dtype=np.float32)
        elif kind == "lane":
            out[a] = np.array([9.0, 0.0])
        else:  # target_pose
            out[a] = np.array([sim.table.x[row] + 0.8, sim.table.y[row], sim.table.heading[row]])
    return out


def _state(env):
    """Everything a refused step must leave alone."""
    sim = env.sim
    provider = sim.providers[0]
    ctl = provider.lane_relative
    live = sim.table.alive_rows
    handles = provider.handles[provider.handles >= 0]
    physics = provider.worlds[0].read_state(handles) if handles.size else None
    return {
        "table": sim.table.data.copy(),
        "ids": [sim.table.ids[r] for r in live.tolist()],
        "owner": sim.table.owner.copy(),
        "lane": sim.table.lane.copy(),
        "clock": (sim.step_count, sim.time),
        "agents": (list(env.agents), sim.agent_active.copy(), sim.agent_events.copy(), sim.agent_done.copy()),
        "route": (sim.route_index.copy(), sim.route_progress.copy()),
        "lane_relative": tuple(
            a.copy() for a in (ctl.track, ctl.pending, ctl.profile_start, ctl.profile_age, ctl.branch)
        ),
        "lane_offset": provider.lane_offset.copy(),
        "physics": None if physics is None else tuple(np.array(v) for v in physics),
        "traffic_rng": [p.rng.bit_generator.state for p in sim.providers[1:] if hasattr(p, "rng")],
    }


def _assert_same(a, b):
    assert a.keys() == b.keys()
    for key in a:
        x, y = a[key], b[key]
        if isinstance(x, np.ndarray):
            np.testing.assert_array_equal(x, y, err_msg=key)
        elif isinstance(x, tuple) and x and isinstance(x[0], np.ndarray):
            for u, v in zip(x, y):
                np.testing.assert_array_equal(u, v, err_msg=key)
        elif key == "agents":
            assert x[0] == y[0], key
            for u, v in zip(x[1:], y[1:]):
                np.testing.assert_array_equal(u, v, err_msg=key)
        else:
            assert x == y, key


def _assert_same_step(one, other):
    obs_a, *rest_a = one
    obs_b, *rest_b = other
    assert obs_a.keys() == obs_b.keys()
    for agent_id in obs_a:
        for key in obs_a[agent_id]:
            np.testing.assert_array_equal(obs_a[agent_id][key], obs_b[agent_id][key], err_msg=f"{agent_id} {key}")
    assert rest_a == rest_b


BAD = [
    (
        "agent_1",
        np.array([0.3, np.nan, 0.0]),
        r"agent_1: continuous action component brake is nan; expected finite numbers",
    ),
    (
        "agent_0",
        np.array([1.0, 0.0]),
        r"agent_0: relative_target_pose action has 2 components; expected 3 \(dx, dy, dheading\)",
    ),
    (
        "agent_2",
        np.array([0.0, np.inf], np.float32),
        r"agent_2: continuous \(lane_relative\) action component lane_change is inf",
    ),
    (
        "agent_3",
        np.zeros(3),
        r"agent_3: target_pose \(lane_relative\) action has 3 components; expected 2 \(speed, lane_change\)",
    ),
    ("agent_4", np.array([[9.0, 0.0]]), r"agent_4: lane action has shape \(1, 2\); expected shape \(2,\)"),
    (
        "agent_1",
        np.array([1 + 1j, 0, 0]),
        r"agent_1: continuous action .* is complex numbers .*expected 3 real numbers",
    ),
    ("agent_0", "fast", r"agent_0: relative_target_pose action 'fast' is not numbers"),
    ("agent_4", None, r"agent_4: lane action None is not numbers"),
]


@pytest.mark.parametrize("who, bad, message", BAD, ids=[f"{w}-{i}" for i, (w, _, _) in enumerate(BAD)])
def test_a_refused_step_changes_nothing_and_the_next_step_is_as_if_it_never_happened(who, bad, message):
    env, fresh = DrivingParallelEnv(_spec()), DrivingParallelEnv(_spec())
    for e in (env, fresh):
        e.reset(seed=3)
        for k in range(5):
            e.step(_actions(e, k))
    assert len(env.sim.table.alive_rows) > len(AGENTS)  # traffic is part of what must stay put
    before = _state(env)
    _assert_same(before, _state(fresh))
    actions = _actions(env, 5)
    actions[who] = bad
    with pytest.raises(ActionError, match=message) as err:
        env.step(actions)
    assert err.value.agent_ids == [who]
    _assert_same(_state(env), before)
    for k in range(5, 9):  # the same valid steps on both: bit-identical results
        _assert_same_step(env.step(_actions(env, k)), fresh.step(_actions(fresh, k)))
        _assert_same(_state(env), _state(fresh))
    env.close()
    fresh.close()


def test_every_bad_agent_of_every_group_is_named_at_once():
    env = DrivingParallelEnv(_spec())
    env.reset(seed=0)
    actions = _actions(env, 0)
    actions["agent_0"] = np.array([np.nan, 0.0, 0.0])
    actions["agent_2"] = np.zeros(5)
    actions["agent_4"] = np.array([np.inf, 0.0])
    with pytest.raises(ActionError) as err:
        env.step(actions)
    assert sorted(err.value.agent_ids) == ["agent_0", "agent_2", "agent_4"]
    for text in (
        "agent_0: relative_target_pose action component dx is nan",
        "agent_2: continuous (lane_relative) action has 5 components",
        "agent_4: lane action component target_speed is inf",
    ):
        assert text in str(err.value)
    assert env.sim.step_count == 0 and env.sim.time == 0.0
    env.close()


def test_check_actions_refuses_what_step_would_and_changes_nothing():
    env = DrivingParallelEnv(_spec())
    env.reset(seed=0)
    before = _state(env)
    actions = _actions(env, 0)
    env.check_actions(actions)  # valid: nothing raised, nothing moved
    actions["agent_1"] = np.array([np.nan, 0.0, 0.0])
    with pytest.raises(ActionError, match="agent_1: continuous action component throttle is nan"):
        env.check_actions(actions)
    with pytest.raises(ActionError, match=r"no action given for live agents \['agent_3'\]"):
        env.check_actions({a: v for a, v in _actions(env, 0).items() if a != "agent_3"})
    _assert_same(_state(env), before)
    env.close()


class CountingPolicy:
    """A social policy that counts its calls: a refused step must not ask it for actions."""

    action_space = "relative_target_pose"

    def __init__(self):
        self.calls = 0

    def act(self, obs):
        self.calls += 1
        return np.tile([0.8, 0.0, 0.0], (len(obs["ego"]), 1))


def test_social_policies_are_not_asked_on_a_refused_step():
    policy = CountingPolicy()
    spec = make_spec([agent(lane=0, offset=10.0), agent(lane=1, offset=10.0, policy="test:count")])
    env = DrivingParallelEnv(spec, policy_resolver=lambda locator, **kw: policy)
    env.reset(seed=0)
    env.step({"agent_0": np.array([0.8, 0.0, 0.0])})
    assert policy.calls == 1
    with pytest.raises(ActionError, match="agent_0: relative_target_pose action component dy is nan"):
        env.step({"agent_0": np.array([0.8, np.nan, 0.0])})
    assert policy.calls == 1 and env.sim.step_count == 1
    env.close()


def test_the_simulation_refuses_before_its_clock_moves():
    env = DrivingParallelEnv(_spec())
    env.reset(seed=0)
    sim = env.sim
    actions = _actions(env, 0)
    actions["agent_3"] = np.array([np.nan, 0.0])
    with pytest.raises(ActionError, match=r"agent_3: target_pose \(lane_relative\) action component speed is nan"):
        sim.step(actions)
    del actions["agent_3"]
    with pytest.raises(ActionError, match=r"agent_3: no target_pose \(lane_relative\) action given this step"):
        sim.step(actions)
    assert (sim.step_count, sim.time) == (0, 0.0)
    env.close()
