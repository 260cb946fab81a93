import warnings

import gymnasium
import numpy as np
import pytest
import torch
from stable_baselines3 import PPO
from stable_baselines3.common.env_checker import check_env

import smarts.env  # noqa: F401  (registers smarts/Driving-v0)
from smarts.core.errors import ActionError
from smarts.core.events import EVENT_NAMES
from smarts.env import DrivingParallelEnv
from smarts.env.batched import BatchedSetupError
from smarts.env.sb3_vec_env import SmartsVecEnv
from tests.builders import agent, make_spec

CRUISE = np.array([1.0, 0.0, 0.0], dtype=np.float32)
SWERVE_RIGHT = np.array([0.8, -0.05, -0.1], dtype=np.float32)


def short_two_agent_spec(episode_steps: int = 40):
    return make_spec([agent(lane=0, offset=10.0), agent(lane=1, offset=10.0)], episode_steps=episode_steps)


def test_two_copies_of_a_two_agent_scenario_are_four_slots_with_stacked_dict_observations():
    vec = SmartsVecEnv.from_scenario("straight_2lane_cruise", n_envs=2)
    raw = DrivingParallelEnv("straight_2lane_cruise")
    assert vec.num_envs == 4
    assert vec.slot_agents == [(0, "agent_0"), (0, "agent_1"), (1, "agent_0"), (1, "agent_1")]
    assert vec.observation_space == raw.observation_space("agent_0")
    assert vec.action_space == raw.action_space("agent_0")

    obs = vec.reset()
    raw_obs, _ = raw.reset(seed=0)
    assert set(obs) == set(vec.observation_space.spaces)
    for key, space in vec.observation_space.spaces.items():
        assert obs[key].shape == (4, *space.shape) and obs[key].dtype == space.dtype
        for slot, (_, name) in enumerate(vec.slot_agents):
            np.testing.assert_array_equal(obs[key][slot], raw_obs[name][key])

    # Each slot's row is its own agent's: rewards and observations match the raw env slot by slot.
    actions = np.stack([CRUISE, CRUISE * 0.5, CRUISE, CRUISE * 0.5])
    obs, rewards, dones, infos = vec.step(actions)
    raw_obs, raw_rewards, *_ = raw.step({"agent_0": CRUISE, "agent_1": CRUISE * 0.5})
    assert rewards.shape == (4,) and rewards.dtype == np.float32
    assert dones.shape == (4,) and dones.dtype == bool and not dones.any()
    assert len(infos) == 4 and all(isinstance(i, dict) and "inactive" not in i for i in infos)
    np.testing.assert_allclose(rewards, [raw_rewards["agent_0"], raw_rewards["agent_1"]] * 2, rtol=1e-6)
    np.testing.assert_array_equal(obs["ego"][1], raw_obs["agent_1"]["ego"])
    assert rewards[0] > rewards[1] > 0  # the faster agent progressed further
    vec.close()
    raw.close()


def test_finished_agent_gets_terminal_observation_once_then_waits_inactive_until_its_copy_resets():
    vec = SmartsVecEnv([short_two_agent_spec(40)] * 2, seed=0)
    first = vec.reset()
    actions = np.stack([SWERVE_RIGHT, CRUISE, CRUISE, CRUISE])  # slot 0 leaves the road
    finished_at = None
    for step in range(40):
        obs, rewards, dones, infos = vec.step(actions)
        if finished_at is None and dones[0]:
            finished_at = step
            info = infos[0]
            assert "off_road" in info["events"] and not info["TimeLimit.truncated"]
            terminal = info["terminal_observation"]
            assert set(terminal) == set(first) and vec.observation_space.contains(terminal)
            assert terminal["events"][EVENT_NAMES.index("off_road")] == 1.0  # the final observation, not a zero filler
            assert info["episode"]["l"] == step + 1 and info["episode"]["r"] < 0
            assert not any(obs[k][0].any() for k in obs)  # its row is zero from now on
        elif finished_at is not None and step < 39:
            assert not dones[0] and rewards[0] == 0.0 and infos[0] == {"inactive": True}
            assert not any(obs[k][0].any() for k in obs)
            assert not dones[1:].any()
    assert finished_at is not None and finished_at < 39
    # Step 40: the step limit ends every other agent; both copies reset within the step.
    assert dones.tolist() == [False, True, True, True]
    for slot in (1, 2, 3):
        assert infos[slot]["TimeLimit.truncated"]
        assert infos[slot]["episode"]["l"] == 40
        assert infos[slot]["terminal_observation"]["events"][-1] == 1.0  # max_steps flagged
        assert not obs["events"][slot].any()  # a fresh episode
    for key in obs:  # every slot holds its agent's first observation of the new episode
        np.testing.assert_array_equal(obs[key], first[key])
    obs, rewards, dones, infos = vec.step(np.stack([CRUISE] * 4))
    assert all("inactive" not in i for i in infos) and (rewards > 0).all()
    vec.close()


def test_ppo_multi_input_policy_trains_on_the_slots_unchanged():
    """SB3's PPO on the adapter, under SB3's own VecEnv check (``VecCheckNan``: every action,
    observation and reward of every step finite, else it raises)."""
    from stable_baselines3.common.vec_env import VecCheckNan

    vec = SmartsVecEnv([short_two_agent_spec(30)] * 2, normalize_actions=True)
    assert vec.action_space == gymnasium.spaces.Box(-1.0, 1.0, (3,), np.float32)
    checked = VecCheckNan(vec, raise_exception=True)
    model = PPO("MultiInputPolicy", checked, n_steps=64, batch_size=64, n_epochs=2, seed=0, device="cpu")
    before = [p.detach().clone() for p in model.policy.parameters()]
    model.learn(256)
    assert model.num_timesteps == 256
    # Episodes ended (by truncation: PPO bootstrapped from their terminal observations) and the
    # adapter's episode records reached SB3's logger buffer.
    assert len(model.ep_info_buffer) > 0
    assert any(not torch.equal(a, b) for a, b in zip(before, model.policy.parameters()))
    action, _ = model.predict(vec.reset(), deterministic=True)
    assert action.shape == (4, 3)
    vec.close()


def test_normalized_actions_map_onto_the_agents_action_box():
    vec = SmartsVecEnv.from_scenario("straight_2lane_cruise", n_envs=1, normalize_actions=True)
    raw = DrivingParallelEnv("straight_2lane_cruise")
    box = raw.action_space("agent_0")
    vec.reset()
    raw.reset(seed=0)
    _, rewards, _, _ = vec.step(np.array([[1.0, 0.0, 0.0], [-1.0, 0.0, 0.0]], dtype=np.float32))
    mid = (box.low + box.high) / 2
    _, raw_rewards, *_ = raw.step(
        {"agent_0": np.array([box.high[0], mid[1], mid[2]]), "agent_1": np.array([box.low[0], mid[1], mid[2]])}
    )
    np.testing.assert_allclose(rewards, [raw_rewards["agent_0"], raw_rewards["agent_1"]], rtol=1e-5)


def test_sb3_check_env_passes_on_the_single_agent_gymnasium_env():
    env = gymnasium.make("smarts/Driving-v0", scenario="straight_2lane_cruise")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # advice about shapes/scales, not failures
        check_env(env, warn=True)
    env.close()


def test_worker_processes_give_the_same_rollout_as_in_process_copies():
    spec = short_two_agent_spec(12)
    in_process = SmartsVecEnv([spec] * 2)
    workers = SmartsVecEnv([spec] * 2, workers=2)
    try:
        assert len(workers.driving.shards) == 2 and not workers.driving.groups  # one copy per worker
        assert workers.num_envs == 4 and workers.observation_space == in_process.observation_space
        a, b = workers.reset(), in_process.reset()
        rng = np.random.default_rng(0)
        space = workers.action_space
        seen = set()
        for _ in range(15):  # slot 0 leaves the road early; the others reach the step limit (12)
            actions = rng.uniform(space.low / 4, space.high / 4, size=(4, *space.shape)).astype(np.float32)
            actions[0] = SWERVE_RIGHT
            a, ra, da, ia = workers.step(actions)
            b, rb, db, ib = in_process.step(actions)
            for key in a:
                np.testing.assert_array_equal(a[key], b[key])
            np.testing.assert_array_equal(ra, rb)
            np.testing.assert_array_equal(da, db)
            for x, y in zip(ia, ib):
                assert sorted(x) == sorted(y)
                if "terminal_observation" in x:
                    np.testing.assert_array_equal(x["terminal_observation"]["ego"], y["terminal_observation"]["ego"])
                    seen.add("truncated" if x["TimeLimit.truncated"] else "terminated")
                seen.update({"inactive"} & set(x))
        assert seen == {"terminated", "truncated", "inactive"}
        assert workers.get_attr("slots", indices=[0, 3]) == [workers.slot_agents] * 2
        # A refused action names the slot before any worker moves, and the pipes stay usable.
        with pytest.raises(ActionError, match=r"slot 0.*not finite"):
            workers.step(np.full((4, 3), np.nan, dtype=np.float32))
        a, ra, *_ = workers.step(np.stack([CRUISE] * 4))
        b, rb, *_ = in_process.step(np.stack([CRUISE] * 4))
        np.testing.assert_array_equal(ra, rb)
        np.testing.assert_array_equal(a["ego"], b["ego"])
    finally:
        workers.close()
        in_process.close()


def test_one_action_space_for_one_policy():
    mixed = make_spec([agent(lane=0), agent(lane=1, action_space="target_pose")])
    with pytest.raises(
        BatchedSetupError,
        match=r"SB3 trains one policy with one Box action space.*2 different.*"
        r"slot 0 \(copy 0, test-scenario, agent_0\): Box.*"
        r"slot 1 \(copy 0, test-scenario, agent_1\): Box",
    ):
        SmartsVecEnv([mixed])


@pytest.mark.parametrize("workers", [0, 2], ids=["in_process", "workers"])
def test_a_bad_action_in_one_copy_steps_no_copy(workers):
    """Every copy checks before any steps: after a refused step the VecEnv goes on exactly like one
    that never saw it."""
    spec = short_two_agent_spec(30)
    vec = SmartsVecEnv([spec] * 2, workers=workers, seed=5)
    fresh = SmartsVecEnv([spec] * 2, seed=5)
    try:
        vec.reset(), fresh.reset()
        good = np.stack([CRUISE, CRUISE * 0.5, CRUISE * 0.7, CRUISE])
        for v in (vec, fresh):
            v.step(good)
        bad = good.copy()
        bad[3, 2] = np.nan  # copy 1, agent_1
        with pytest.raises(ActionError, match=r"1/agent_1|slot 3"):
            vec.step(bad)
        if not workers:
            assert vec.driving.groups[0].sim.episode_step.tolist() == [1, 1]
        with pytest.raises(ActionError, match=r"SmartsVecEnv: actions: expected shape \(4, 3\) .* got shape \(4, 2\)"):
            vec.step(good[:, :2])
        for _ in range(3):
            a, ra, da, _ = vec.step(good)
            b, rb, db, _ = fresh.step(good)
            for key in a:
                np.testing.assert_array_equal(a[key], b[key])
            np.testing.assert_array_equal(ra, rb)
            np.testing.assert_array_equal(da, db)
    finally:
        vec.close()
        fresh.close()
