"""The sensors give the same observations on one thread or several (``SMARTS_SENSOR_THREADS``)."""

import numpy as np
import pytest

from smarts.diagnostic.scenarios import sensor_scenario
from smarts.env import DrivingParallelEnv
from smarts.sensors.rays import PARALLEL_AGENTS, parallel_worth_it


def _rollout(steps: int = 6) -> list[dict]:
    env = DrivingParallelEnv(sensor_scenario(PARALLEL_AGENTS + 2, 12, 50))
    obs, _ = env.reset(seed=3)
    seen = [obs]
    for _ in range(steps):
        actions = {a: np.concatenate([[0.8, 0.0, 0.0], np.zeros(env.action_space(a).shape[0] - 3)]) for a in env.agents}
        obs, *_ = env.step(actions)
        seen.append(obs)
    env.close()
    return seen


def test_threaded_sensors_give_the_single_threads_observations(monkeypatch):
    monkeypatch.setenv("SMARTS_SENSOR_THREADS", "1")
    assert not parallel_worth_it(PARALLEL_AGENTS + 2)
    one = _rollout()
    monkeypatch.setenv("SMARTS_SENSOR_THREADS", "2")
    assert parallel_worth_it(PARALLEL_AGENTS + 2)  # the threaded kernels really run
    two = _rollout()
    keys = {"rasters", "rgb", "lidar", "lidar_hit", "neighbours"}
    assert keys <= set(one[0]["agent_0"])
    for a_step, b_step in zip(one, two):
        for agent, obs in a_step.items():
            for key, value in obs.items():
                np.testing.assert_array_equal(value, b_step[agent][key], err_msg=f"{agent} {key}")


def test_a_bad_thread_count_is_a_clear_error(monkeypatch):
    monkeypatch.setenv("SMARTS_SENSOR_THREADS", "many")
    with pytest.raises(ValueError, match=r"SMARTS_SENSOR_THREADS: expected a positive integer, got 'many'"):
        parallel_worth_it(PARALLEL_AGENTS)
