import numpy as np
import pytest
from pettingzoo.test import parallel_api_test

from smarts.dynamics.action_spaces import ActionError
from smarts.env import DrivingParallelEnv
from tests.builders import agent, make_spec


def test_pettingzoo_parallel_api():
    env = DrivingParallelEnv("intersection_4way_left")
    parallel_api_test(env, num_cycles=200)
    env.close()


def test_observations_lie_in_their_spaces_and_agents_are_named_by_index():
    env = DrivingParallelEnv("straight_2lane_cruise")
    obs, infos = env.reset(seed=0)
    assert env.possible_agents == ["agent_0", "agent_1"]
    for a in env.agents:
        assert env.observation_space(a).contains(obs[a])
        assert env.observation_space(a) is env.observation_space(a)
    # agent_1 is 20 m ahead in the left lane: agent_0 sees it ahead-left.
    nb = obs["agent_0"]["neighbours"]
    assert obs["agent_0"]["neighbour_mask"][0] == 1.0
    assert nb[0, 0] == pytest.approx(20.0, abs=1e-4) and nb[0, 1] == pytest.approx(3.2, abs=1e-4)
    # The route waypoints lie straight ahead along the lane, 2 m apart.
    wp = obs["agent_0"]["waypoints"][0]
    np.testing.assert_allclose(wp[:5, 0], [0, 2, 4, 6, 8], atol=1e-4)
    np.testing.assert_allclose(wp[:5, 1], 0.0, atol=1e-4)
    # Left of lane 0 is lane 1; right of it is nothing.
    assert obs["agent_0"]["waypoint_mask"][1].all() and not obs["agent_0"]["waypoint_mask"][2].any()
    np.testing.assert_allclose(obs["agent_0"]["waypoints"][1, :3, 1], 3.2, atol=1e-4)


def test_nan_action_is_an_error_naming_the_agent_and_state_is_untouched():
    env = DrivingParallelEnv("straight_2lane_cruise")
    env.reset(seed=0)
    before = env.sim.table.x.copy()
    with pytest.raises(ActionError, match="agent_1.*dheading is nan"):
        env.step({"agent_0": np.array([1.0, 0, 0]), "agent_1": np.array([1.0, 0, np.nan])})
    # The error came before anything moved.
    np.testing.assert_array_equal(env.sim.table.x, before)


def test_missing_and_unknown_agents_are_errors():
    env = DrivingParallelEnv("straight_2lane_cruise")
    env.reset(seed=0)
    with pytest.raises(ActionError, match="no action given for live agents \\['agent_1'\\]"):
        env.step({"agent_0": np.array([1.0, 0, 0])})
    with pytest.raises(ActionError, match="not live: \\['agent_9'\\]"):
        env.step({"agent_0": np.zeros(3), "agent_1": np.zeros(3), "agent_9": np.zeros(3)})


def test_done_agents_leave_and_the_others_continue():
    spec = make_spec([agent(lane=0, offset=10.0), agent(lane=1, offset=10.0)])
    env = DrivingParallelEnv(spec)
    env.reset(seed=0)
    # agent_0 swerves right off the road; agent_1 cruises on.
    for _ in range(40):
        actions = {a: np.array([1.0, 0.0, 0.0]) for a in env.agents}
        if "agent_0" in actions:
            actions["agent_0"] = np.array([0.8, -0.05, -0.1])  # steer right
        obs, rewards, terms, truncs, infos = env.step(actions)
        if "agent_0" in terms and terms["agent_0"]:
            assert "off_road" in infos["agent_0"]["events"]
            assert rewards["agent_0"] < -5
            break
    assert env.agents == ["agent_1"]
    obs, *_ = env.step({"agent_1": np.array([1.0, 0, 0])})
    assert list(obs) == ["agent_1"]


def test_progress_reward_and_truncation():
    env = DrivingParallelEnv(make_spec([agent()], episode_steps=3))
    env.reset(seed=0)
    for k in range(3):
        obs, rewards, terms, truncs, infos = env.step({"agent_0": np.array([1.0, 0, 0])})
        assert rewards["agent_0"] == pytest.approx(1.0, abs=1e-6)
    assert truncs["agent_0"] and not terms["agent_0"]
    assert env.agents == []


def test_render_returns_an_rgb_image_with_the_vehicles():
    env = DrivingParallelEnv("intersection_4way_left", render_mode="rgb_array")
    env.reset(seed=0)
    frame = env.render()
    assert frame.dtype == np.uint8 and frame.ndim == 3 and frame.shape[2] == 3
    agent_red = (frame[..., 0] > 200) & (frame[..., 1] < 100) & (frame[..., 2] < 100)
    assert agent_red.sum() > 10
