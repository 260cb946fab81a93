import gymnasium
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env

import smarts.env  # noqa: F401  (registers smarts/Driving-v0)


def test_gymnasium_make_and_check_env():
    env = gymnasium.make("smarts/Driving-v0", scenario="straight_2lane_cruise")
    check_env(env.unwrapped, skip_render_check=True)
    env.close()


def test_single_agent_keeps_only_the_chosen_agent():
    env = gymnasium.make("smarts/Driving-v0", scenario="straight_2lane_cruise", agent="agent_1")
    obs, info = env.reset(seed=0)
    assert env.unwrapped.sim.agent_ids == ["agent_1"]
    assert obs["neighbour_mask"].sum() == 0  # the other agent is not in the episode
    obs, reward, terminated, truncated, info = env.step(np.array([1.0, 0.0, 0.0], dtype=np.float32))
    assert reward == pytest.approx(1.0, abs=1e-6) and not terminated and not truncated


def test_unknown_agent_is_a_clear_error():
    with pytest.raises(ValueError, match="no agent 'agent_7'"):
        gymnasium.make("smarts/Driving-v0", scenario="straight_2lane_cruise", agent="agent_7")


def test_render_rgb_array():
    env = gymnasium.make("smarts/Driving-v0", scenario="straight_2lane_cruise", render_mode="rgb_array")
    env.reset(seed=0)
    assert env.render().shape[2] == 3
