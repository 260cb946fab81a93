import pickle

import pytest
import torch
from torchrl.envs.utils import check_env_specs, step_mdp

from smarts.env import DrivingParallelEnv
from smarts.env.torchrl_env import (
    SmartsTorchRLEnv,
    env_factory,
    make_parallel_env,
    make_serial_env,
)

OBS_SHAPES = {
    "ego": (12,),
    "neighbours": (8, 9),
    "neighbour_mask": (8,),
    "waypoints": (3, 20, 3),
    "waypoint_mask": (3, 20),
    "goal": (4,),
    "signal": (4,),
    "events": (8,),
}


def test_single_agent_env_has_flat_keys_and_passes_check_env_specs():
    env = SmartsTorchRLEnv("straight_2lane_cruise", single_agent=True)
    assert env.possible_agents == ["agent_0"]
    check_env_specs(env)
    obs_spec = env.observation_spec["observation"]
    assert {k: tuple(obs_spec[k].shape) for k in OBS_SHAPES} == OBS_SHAPES
    assert env.action_spec.shape == (3,) and env.reward_spec.shape == (1,)
    assert set(env.done_keys) == {"done", "terminated", "truncated"}
    # A scenario whose only learner is agent_0 (the other agent is social) is single-agent by itself.
    assert SmartsTorchRLEnv("t_junction_social").single_agent
    env.close()


def test_multi_agent_env_groups_agents_and_passes_check_env_specs():
    env = SmartsTorchRLEnv("intersection_4way_left")
    check_env_specs(env)
    group = env.observation_spec["agents"]
    assert group.shape == (2,)
    assert {k: tuple(group["observation", k].shape) for k in OBS_SHAPES} == {k: (2, *s) for k, s in OBS_SHAPES.items()}
    assert group["mask"].dtype == torch.bool and group["mask"].shape == (2,)
    assert env.full_action_spec["agents", "action"].shape == (2, 3)
    assert env.full_reward_spec["agents", "reward"].shape == (2, 1)
    assert env.full_done_spec["agents", "done"].shape == (2, 1) and env.full_done_spec["done"].shape == (1,)
    env.close()


def test_single_agent_rollout_resets_itself_when_the_episode_ends():
    env = SmartsTorchRLEnv("straight_2lane_cruise", single_agent=True)
    env.set_seed(0)
    torch.manual_seed(0)
    data = env.rollout(300, break_when_any_done=False)
    assert data.batch_size == (300,)
    ends = data["next", "done"][:, 0].nonzero()[:, 0]
    assert len(ends) >= 1  # random actions leave the road, or the 250-step limit cuts the episode
    first = data["observation", "ego"][0]
    for t in ends[ends < 299].tolist():  # the step after an end starts a fresh episode
        assert torch.equal(data["observation", "ego"][t + 1], first)
        assert not data["done"][t + 1].any()
    assert torch.isfinite(data["next", "reward"]).all()
    assert torch.equal(data["next", "done"], data["next", "terminated"] | data["next", "truncated"])
    env.close()


def test_multi_agent_rollout_masks_finished_agents_and_ends_when_none_is_live():
    env = SmartsTorchRLEnv("straight_2lane_cruise")
    env.set_seed(0)
    torch.manual_seed(0)
    data = env.rollout(300, break_when_any_done=False)
    live_before, live_after = data["agents", "mask"], data["next", "agents", "mask"]
    episode_end = data["next", "done"][:, 0]
    assert episode_end.any()
    assert torch.equal(episode_end, ~live_after.any(-1))
    assert torch.equal(data["next", "agents", "done"][..., 0], ~live_after)
    # Within an episode the live set carries over from step to step (no partial resets).
    carry = ~episode_end[:-1]
    assert torch.equal(live_before[1:][carry], live_after[:-1][carry])
    # Agents that had finished before a step get zero reward and zero observations from it.
    gone = ~live_before
    assert gone.any()
    assert (data["next", "agents", "reward"][gone] == 0).all()
    assert (data["next", "agents", "observation", "ego"][gone] == 0).all()
    # The first episode runs into the 250-step limit: the episode is truncated, not terminated.
    assert episode_end[249] and data["next", "truncated"][249].item() and not data["next", "terminated"][249].item()
    # A new episode starts with every agent live.
    starts = episode_end[:-1].nonzero()[:, 0] + 1
    assert live_before[starts].all() and live_before[0].all()
    env.close()


def test_mask_goes_false_for_a_finished_agent_while_the_other_drives_on():
    env = SmartsTorchRLEnv("intersection_4way_left")
    td = env.reset()
    swerve_off_road = torch.tensor([0.8, 2.0, 0.1])
    straight_on = torch.tensor([0.8, 0.0, 0.0])
    for _ in range(100):
        td["agents", "action"] = torch.stack([swerve_off_road, straight_on])
        td = env.step(td)
        nxt = td["next"]
        if not nxt["agents", "mask"][0]:
            break
        td = step_mdp(td)
    else:
        pytest.fail("agent_0 never left the road")
    assert nxt["agents", "mask"].tolist() == [False, True]
    assert nxt["agents", "done"][:, 0].tolist() == [True, False]
    assert nxt["agents", "terminated"][:, 0].tolist() == [True, False]
    assert not nxt["done"].item()
    assert nxt["agents", "reward"][0].item() < 0  # the off-road penalty
    assert nxt["agents", "observation", "ego"][0].abs().sum() > 0  # its final observation
    # From now on agent_0's actions are ignored (even NaN) and its entries stay zero / done.
    td = step_mdp(td)
    td["agents", "action"] = torch.stack([torch.full((3,), float("nan")), straight_on])
    nxt = env.step(td)["next"]
    assert nxt["agents", "mask"].tolist() == [False, True]
    assert nxt["agents", "done"][:, 0].tolist() == [True, False]
    assert nxt["agents", "reward"][0].item() == 0.0 and nxt["agents", "reward"][1].item() > 0
    assert (nxt["agents", "observation", "ego"][0] == 0).all()
    assert nxt["agents", "observation", "ego"][1].abs().sum() > 0
    env.close()


def test_same_seed_gives_the_same_rollout_and_another_seed_other_traffic():
    def rollout(env, seed):
        env.set_seed(seed)
        torch.manual_seed(0)  # the random actions
        return env.rollout(80, break_when_any_done=False)

    env = SmartsTorchRLEnv("intersection_4way_signal_traffic")  # built-in traffic draws from the seed
    first = rollout(env, 5)
    again = rollout(SmartsTorchRLEnv("intersection_4way_signal_traffic"), 5)
    assert (first == again).all()
    other = rollout(env, 6)
    assert not torch.equal(first["next", "observation", "neighbours"], other["next", "observation", "neighbours"])
    env.close()


def test_single_agent_picks_the_named_agent_and_rejects_unknown_ones():
    env = SmartsTorchRLEnv("intersection_4way_left", agent="agent_1")
    assert env.single_agent and env.possible_agents == ["agent_1"]
    alone = env.reset()["observation", "waypoints"]
    both = SmartsTorchRLEnv("intersection_4way_left").reset()["agents", "observation", "waypoints"]
    assert torch.equal(alone, both[1]) and not torch.equal(alone, both[0])  # agent_1's route
    with pytest.raises(ValueError, match="no learning agent 'agent_9'"):
        SmartsTorchRLEnv("intersection_4way_left", agent="agent_9")
    with pytest.raises(ValueError, match="a built env keeps all its learning agents"):
        SmartsTorchRLEnv(DrivingParallelEnv("intersection_4way_left"), single_agent=True)
    env.close()


def test_serial_batch_of_multi_agent_envs_keeps_the_agent_dim():
    env = make_serial_env("intersection_4way_left", 2)
    check_env_specs(env)
    env.set_seed(3)
    data = env.rollout(20, break_when_any_done=False)
    assert data.batch_size == (2, 20)
    assert data["next", "agents", "observation", "waypoints"].shape == (2, 20, 2, 3, 20, 3)
    assert data["next", "agents", "mask"].shape == (2, 20, 2)
    env.close()


def _fast_start_method() -> str:
    """fork copies this process into the workers: fine unless a SUMO already runs here."""
    import libsumo

    return "spawn" if libsumo.simulation.isLoaded() else "fork"


def test_env_factory_survives_pickling_for_spawned_workers():
    make = pickle.loads(pickle.dumps(env_factory("intersection_4way_left", single_agent=True, agent="agent_1")))
    env = make()
    assert isinstance(env, SmartsTorchRLEnv) and env.possible_agents == ["agent_1"]
    env.close()


def test_two_worker_processes_each_run_their_own_sumo():
    """libsumo holds one SUMO per process: two SUMO-traffic envs side by side need workers."""
    env = make_parallel_env("highway_merge_traffic", 2, mp_start_method=_fast_start_method())
    try:
        env.set_seed(7)  # the workers get different seeds, hence different traffic
        forward = torch.tensor([1.2, 0.0, 0.0]).expand(2, 3)
        data = env.rollout(60, policy=lambda td: td.set("action", forward), break_when_any_done=False)
    finally:
        env.close()
    assert data.batch_size == (2, 60)
    seen = data["next", "observation", "neighbour_mask"].sum(dim=(-1, -2))
    assert (seen > 0).all()  # both SUMOs sent traffic past the agent
    assert not torch.equal(data[0]["next", "observation", "neighbours"], data[1]["next", "observation", "neighbours"])
