"""The batched backend: B episodes as one simulation give, per episode, what a single env gives."""

import dataclasses

import numpy as np
import pytest
import torch
from torchrl.envs.utils import check_env_specs

from smarts.benchmark.suites import load_suite
from smarts.core.errors import ActionError
from smarts.env.batched import BatchedDriving, BatchedSetupError
from smarts.env.parallel_env import DrivingParallelEnv
from smarts.env.sb3_vec_env import SmartsVecEnv
from smarts.env.task_rewards import RewardWeights, reward_factory
from smarts.env.torchrl_env import SmartsBatchedEnv
from smarts.scenario import map_path, replace
from smarts.sensors.interface import AgentInterface
from tests.builders import agent, make_spec

PLATOON = AgentInterface(lead=True, ahead=True)


def _adaptive(*names: str, controller: str = "lane_relative") -> list:
    """Adaptive suite scenarios on RelativeTargetPose, by default with lane-relative commands (as training)."""
    suite = {s.name: s.spec for s in load_suite("adaptive").scenarios}
    out = []
    for name in names:
        spec = suite[name]
        agents = [replace(a, action_space="relative_target_pose", controller=controller) for a in spec.agents]
        out.append(replace(spec, agents=agents))
    return out


def _platoon_reward():
    return reward_factory(RewardWeights(task="platoon"))


@pytest.mark.parametrize("controller", ["lane_relative", "direct"])
def test_episode_with_seed_s_follows_the_single_env_with_seed_s(controller):
    """Four episodes of a two-agent scenario with traffic and a signalled one (on two maps, one
    simulation), each against a single env reset with the same seed and given the same actions:
    observations, rewards and end flags equal bit for bit over whole episodes, through the
    batch's auto-resets."""
    specs = (
        _adaptive("a02_straight_two_followers_low", "a09_lead_turns_right_at_signal_medium", controller=controller) * 2
    )
    batch = BatchedDriving(specs, observation=PLATOON, reward_factory=_platoon_reward())
    assert len(batch.groups) == 1 and batch.groups[0].sim.map_stack.num_maps == 2
    assert all(group.sim.batch_stages for group in batch.groups)  # traffic stepped in one call per spec
    resets, compared = _compare_with_single_envs(batch, specs, steps=420)
    assert resets >= 2 and compared > 1000


def test_every_map_of_the_platoon_task_in_one_simulation_gives_the_single_envs_episodes():
    """All scenarios of the adaptive suite (seven maps) stepped as one simulation: each copy's
    observations, rewards and end flags equal its single env's bit for bit."""
    suite = load_suite("adaptive").scenarios
    specs = _adaptive(*(s.name for s in suite))
    batch = BatchedDriving(specs, observation=PLATOON, reward_factory=_platoon_reward())
    assert len(batch.groups) == 1
    assert batch.groups[0].sim.map_stack.num_maps == len({map_path(s) for s in specs}) >= 5
    _, compared = _compare_with_single_envs(batch, specs, steps=150)
    assert compared >= 150 * len(specs)


def _compare_with_single_envs(batch: BatchedDriving, specs: list, steps: int) -> tuple[int, int]:
    """Step ``batch`` with random commands beside one single env per copy (same seeds, same
    actions) and assert every slot's results equal; returns (resets, agent-steps compared)."""
    batch.set_seed(7)
    first = batch.reset()
    singles = [DrivingParallelEnv(s, observation=PLATOON, reward=_platoon_reward()()) for s in specs]
    episode = [0] * len(specs)
    single_obs = [env.reset(seed=7 + i * 100_003)[0] for i, env in enumerate(singles)]
    slot = {key: j for j, key in enumerate(batch.slots)}

    def check(obs_batch, obs_single, copy):
        for a, o in obs_single.items():
            for key, value in o.items():
                np.testing.assert_array_equal(value, obs_batch[key][slot[(copy, a)]], err_msg=f"copy {copy} {a} {key}")

    for i in range(len(specs)):
        check(first, single_obs[i], i)
    rng = np.random.default_rng(3)
    resets = compared = 0
    box = batch.action_space
    for _ in range(steps):
        commands = rng.uniform(box.low, box.high, size=(batch.num_slots, box.shape[0]))
        res = batch.step(commands)
        for i, env in enumerate(singles):
            acting = {a: commands[slot[(i, a)]] for a in env.agents}
            obs, rew, term, trunc, _ = env.step(acting)
            check(res.obs, obs, i)
            for a in acting:
                j = slot[(i, a)]
                assert res.acted[j]
                assert rew[a] == res.reward[j].item() or abs(rew[a] - res.reward[j]) < 1e-5 * max(1.0, abs(rew[a]))
                assert (term[a], trunc[a]) == (res.terminated[j], res.truncated[j])
                compared += 1
            if not env.agents:
                episode[i] += 1
                resets += 1
                first_obs, _ = env.reset(seed=7 + i * 100_003 + episode[i])
                assert all(res.restarted[slot[(i, a)]] for a in env.possible_agents)
                check(res.first, first_obs, i)
    return resets, compared


def test_torchrl_env_gives_the_same_tensors_in_this_process_and_spread_over_workers():
    """Same seeds and actions: the copies as one simulation here and split over two worker
    processes (each a simulation of its share) give equal tensors, waiting slots and resets included."""
    specs = _adaptive("a01_straight_free", "a02_straight_two_followers_low", "a08_lead_turns_left_at_junction")
    kwargs = dict(observation=PLATOON, reward_factory=_platoon_reward())
    here, split = SmartsBatchedEnv(specs, **kwargs), SmartsBatchedEnv(specs, workers=2, **kwargs)
    try:
        check_env_specs(split)
        assert len(split.driving.shards) == 2 and not split.driving.groups
        assert here.slots == split.slots and here.batch_size == split.batch_size
        for env in (here, split):
            env.set_seed(11)
        td_here, td_split = here.reset(), split.reset()
        gen = torch.Generator().manual_seed(0)
        resets = 0
        for t in range(300):
            action = torch.rand((here.batch_size[0], 2), generator=gen) * 2 - 1
            td_here = here.step(td_here.set("action", action.clone()))
            td_split = split.step(td_split.set("action", action.clone()))
            for key in td_here["next"].keys(include_nested=True, leaves_only=True):
                assert torch.equal(td_here["next", key], td_split["next", key]), (t, key)
            td_here, td_split = here.step_mdp(td_here), split.step_mdp(td_split)
            done = td_here["done"].clone()
            if done.any():
                resets += 1
                td_here = here.reset(td_here.set("_reset", done.clone()))
                td_split = split.reset(td_split.set("_reset", done.clone()))
                for key in td_here.keys(include_nested=True, leaves_only=True):
                    assert torch.equal(td_here[key], td_split[key]), (t, key)
        assert resets >= 2
    finally:
        here.close()
        split.close()


def test_episodes_of_a_batch_do_not_see_each_other():
    """Two episodes start the agent at the same place: a single episode neither collides nor
    has neighbours, so in the batch neither do they."""
    spec = make_spec([agent(offset=10.0, speed=5.0)], episode_steps=30)
    batch = BatchedDriving([spec, spec, spec])
    obs = batch.reset()
    assert obs["neighbour_mask"].sum() == 0
    for _ in range(10):
        res = batch.step(np.tile([[1.0, 0.0, 0.0]], (3, 1)))
        assert not res.obs["events"][:, 0].any()  # no collision
        assert res.obs["neighbour_mask"].sum() == 0


def test_scenarios_that_cannot_be_batched_are_refused_naming_why():
    """What stays refused now that SUMO copies (in worker processes), social agents and mixed
    action spaces batch: a batch without a learning agent, and learners whose observations differ."""
    suite = {s.name: s.spec for s in load_suite("adaptive").scenarios}
    social = replace(
        suite["a01_straight_free"],
        agents=[replace(a, policy="zoo:keep-lane") for a in suite["a01_straight_free"].agents],
    )
    with pytest.raises(BatchedSetupError, match=r"every agent has a policy; at least one must learn"):
        BatchedDriving([social])
    plain, lead = make_spec([agent()]), make_spec([agent(interface={"lead": True})])
    with pytest.raises(BatchedSetupError, match=r"agent_0's observation space differs from test-scenario's agent_0"):
        BatchedDriving([plain, lead])


def test_bad_actions_raise_naming_the_agents_and_change_nothing():
    spec = make_spec([agent(offset=10.0, speed=5.0)], episode_steps=30)
    batch = BatchedDriving([spec, spec])
    batch.reset()
    x = batch.groups[0].sim.table.x.copy()
    actions = np.tile([[1.0, 0.0, 0.0]], (2, 1))
    actions[1, 0] = np.nan
    with pytest.raises(ActionError, match="1/agent_0"):
        batch.step(actions)
    np.testing.assert_array_equal(batch.groups[0].sim.table.x, x)
    assert batch.groups[0].sim.episode_step.tolist() == [0, 0]


def test_sb3_vec_env_reports_each_end_once_and_restarts_copies_in_the_step():
    specs = _adaptive("a01_straight_free", "a02_straight_two_followers_low")
    vec = SmartsVecEnv(specs, observation=PLATOON, reward_factory=_platoon_reward(), normalize_actions=True, seed=3)
    assert vec.num_envs == 3 and vec.slot_agents == [(0, "agent_0"), (1, "agent_0"), (1, "agent_1")]
    obs = vec.reset()
    assert set(obs) == set(vec.observation_space.spaces) and obs["ego"].shape == (3, 12)
    ends = 0
    rng = np.random.default_rng(0)
    for _ in range(600):
        obs, rewards, dones, infos = vec.step(rng.uniform(-1, 1, size=(3, 2)).astype(np.float32))
        for j in np.flatnonzero(dones):
            ends += 1
            assert {"terminal_observation", "episode", "TimeLimit.truncated"} <= set(infos[j])
            assert infos[j]["episode"]["l"] > 0
        for j, info in enumerate(infos):
            if info.get("inactive"):
                assert rewards[j] == 0 and not dones[j] and not obs["ego"][j].any()
    assert ends >= 3
    vec.close()


def test_episode_recorder_logs_the_same_episode_on_both_backends():
    """The benchmark's EpisodeRecorder on one copy of a batch (``episode_sim``) writes the log a
    single env gives for the same seed and actions, so the metrics score both alike."""
    from smarts.benchmark.recorder import EpisodeRecorder

    specs = _adaptive("a02_straight_two_followers_low", "a08_lead_turns_left_at_junction")
    batch = BatchedDriving(specs, observation=PLATOON)
    batch.set_seed(5)
    batch.reset()
    singles = [DrivingParallelEnv(s, observation=PLATOON) for s in specs]
    for i, env in enumerate(singles):
        env.reset(seed=5 + i * 100_003)
    meta = dict(task="adaptive", episode=0, seed=5, time_limit=25.0)
    recorders = [
        EpisodeRecorder(batch.episode_sim(i), env.possible_agents, scenario=s.name, **meta)
        for i, (s, env) in enumerate(zip(specs, singles))
    ]  # fmt: skip
    reference = [
        EpisodeRecorder(env.sim, env.possible_agents, scenario=s.name, **meta) for s, env in zip(specs, singles)
    ]
    open_copies = [True] * len(specs)
    batch.add_step_listener(lambda: [r.record() for r, live in zip(recorders, open_copies) if live])
    for env, rec in zip(singles, reference):
        env.add_step_listener(lambda sim, rec=rec: rec.record())
    slot = {key: j for j, key in enumerate(batch.slots)}
    rng = np.random.default_rng(1)
    for _ in range(300):
        commands = rng.uniform(-1.0, 1.0, size=(batch.num_slots, 2))
        res = batch.step(commands)
        for i, env in enumerate(singles):
            if env.agents:
                env.step({a: commands[slot[(i, a)]] for a in env.agents})
            if res.restarted[[slot[(i, a)] for a in env.possible_agents]].any():
                open_copies[i] = False
        if not any(open_copies):
            break
    for mine, theirs in zip(recorders, reference):
        a, b = mine.finish(), theirs.finish()
        assert set(a.agents) == set(b.agents) and a.agents
        assert a.initial_route_distance == b.initial_route_distance and a.end_time == b.end_time
        for aid in a.agents:
            for field in dataclasses.fields(a.agents[aid]):
                x, y = getattr(a.agents[aid], field.name), getattr(b.agents[aid], field.name)
                np.testing.assert_array_equal(x, y, err_msg=f"{aid} {field.name}")
