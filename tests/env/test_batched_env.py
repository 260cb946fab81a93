"""SmartsBatchedEnv: every learning agent of every scenario copy is a slot of one TorchRL env."""

import numpy as np
import pytest
import torch
from torchrl.data import Bounded
from torchrl.envs.utils import check_env_specs

from smarts.core.errors import ActionError
from smarts.env.batched import BatchedSetupError
from smarts.env.parallel_env import DrivingParallelEnv
from smarts.env.task_rewards import RewardWeights, reward_factory
from smarts.env.torchrl_env import SmartsBatchedEnv
from tests.builders import agent, make_spec


def _specs():
    one = make_spec([agent(offset=10.0, speed=10.0, goal={"road": "main", "offset": 60.0})], episode_steps=60)
    # Two agents: the first reaches its goal long before the second.
    two = make_spec(
        [
            agent(offset=40.0, speed=10.0, goal={"road": "main", "offset": 60.0}),
            agent(lane=1, offset=10.0, speed=10.0, goal={"road": "main", "offset": 150.0}),
        ],
        episode_steps=60,
    )
    return [one, two]


def test_slots_are_every_agent_of_every_copy_and_specs_check():
    env = SmartsBatchedEnv(_specs())
    assert env.batch_size == torch.Size([3])
    assert env.slots == [(0, "agent_0"), (1, "agent_0"), (1, "agent_1")]
    check_env_specs(env)


def _one_metre_per_step(td):
    return td.set("action", torch.tensor([[1.0, 0.0, 0.0]]).expand(td.batch_size[0], 3).clone())


def test_a_finished_agent_waits_until_its_copy_restarts():
    env = SmartsBatchedEnv(_specs())
    env.set_seed(0)
    td = env.rollout(80, policy=_one_metre_per_step, break_when_any_done=False)
    valid = td["valid"][..., 0].numpy()  # [slots, time]
    done = td["next", "done"][..., 0].numpy()
    steps = td["next", "agent_steps"][..., 0].numpy()
    # Slot 1 (agent_0 of the two-agent copy) reaches its goal 20 m on, at step 20...
    first = int(np.flatnonzero(done[1])[0])
    assert first == pytest.approx(19, abs=1)
    assert steps[1, first] == first + 1
    # ... then waits, with zero observations, while its partner drives on.
    partner_end = int(np.flatnonzero(done[2])[0])
    assert partner_end > first + 10
    assert not valid[1, first + 1 : partner_end + 1].any()
    assert not td["observation", "ego"][1, first + 1 : partner_end + 1].any()
    assert (td["next", "reward"][1, first + 1 : partner_end + 1] == 0).all()
    # The copy restarts when the partner ends: both slots live again from the next step.
    assert valid[1, partner_end + 1] and valid[2, partner_end + 1]
    assert (valid[0] | done[0]).all()  # the single-agent copy never waits


def test_same_seed_same_rollout_and_task_rewards_reach_the_slots():
    def rollout():
        env = SmartsBatchedEnv(_specs(), reward_factory=reward_factory(RewardWeights(task="drive")))
        env.set_seed(7)
        torch.manual_seed(0)
        return env.rollout(30, break_when_any_done=False)

    a, b = rollout(), rollout()
    assert torch.equal(a["next", "observation", "ego"], b["next", "observation", "ego"])
    assert torch.equal(a["next", "reward"], b["next", "reward"])
    assert a["next", "reward"].abs().sum() > 0


def test_mixed_action_spaces_get_per_slot_bounds_and_padding_slots_never_act():
    """Copies on RelativeTargetPose, Continuous and Lane: one ``Bounded`` action spec whose rows
    are each slot's own box (the narrower Lane action in the first two columns), padded with slots
    that stay invalid, never end and get no reward; torchrl's spec check passes."""
    continuous = make_spec([agent(offset=10.0, speed=10.0, action_space="continuous")], episode_steps=60)
    lane = make_spec([agent(offset=10.0, speed=10.0, action_space="lane")], episode_steps=60)
    specs = [_specs()[0], continuous, lane]
    env = SmartsBatchedEnv(specs, slots=5)
    try:
        assert env.batch_size == torch.Size([5])
        assert env.slots == [(0, "agent_0"), (1, "agent_0"), (2, "agent_0"), (-1, ""), (-1, "")]
        spec = env.action_spec
        assert isinstance(spec, Bounded) and spec.shape == torch.Size([5, 3])
        for j, s in enumerate(specs):
            box = DrivingParallelEnv(s).action_space("agent_0")
            width = box.shape[0]
            assert torch.equal(spec.space.low[j, :width], torch.from_numpy(box.low)), j
            assert torch.equal(spec.space.high[j, :width], torch.from_numpy(box.high)), j
        assert float(spec.space.high[2, 2]) == float(spec.space.low[2, 2]) == 0.0  # lane: two numbers
        check_env_specs(env)
        env.set_seed(0)
        td = env.rollout(70, break_when_any_done=False)  # random actions within each slot's box
        valid, done = td["valid"][..., 0], td["next", "done"][..., 0]  # [slots, time]
        assert valid[:3].any(-1).all() and not valid[3:].any()
        assert not done[3:].any() and not td["next", "reward"][3:].any()
        assert done[:3].any(-1).all()  # every real slot ended (episode_steps 60)
    finally:
        env.close()


def test_copies_must_share_one_observation_space_and_slots_cover_the_agents():
    lead = make_spec([agent(offset=10.0, speed=10.0, interface={"lead": True})])
    with pytest.raises(BatchedSetupError, match=r"agent_0's observation space differs .* give one interface"):
        SmartsBatchedEnv([_specs()[0], lead])
    with pytest.raises(ValueError, match="slots: 2 is fewer than the 3 learning agents"):
        SmartsBatchedEnv(_specs(), slots=2)


def test_a_bad_action_in_one_copy_steps_no_copy():
    env = SmartsBatchedEnv(_specs())
    env.set_seed(0)
    td = env.reset()
    td = _one_metre_per_step(td)
    td["action"][2, 1] = float("nan")  # copy 1, agent_1
    with pytest.raises(ActionError, match=r"1/agent_1.* not finite"):
        env.step(td)
    sim = env.driving.groups[0].sim
    assert sim.episode_step.tolist() == [0, 0]
    td = _one_metre_per_step(env.reset())
    env.step(td)
    assert sim.episode_step.tolist() == [1, 1]
    with pytest.raises(ActionError, match=r"SmartsBatchedEnv: actions: expected shape \(3, 3\)"):
        env.step(td.set("action", torch.zeros(3, 2)))
    assert sim.episode_step.tolist() == [1, 1]


def test_learners_with_narrower_actions_than_a_social_agent_step():
    """A social agent on direct RelativeTargetPose (3 components) beside learners giving
    lane-relative commands (2): the learners' array is as wide as their own actions."""
    from smarts.env.batched import BatchedDriving
    from train.run import training_spec

    spec = training_spec("t_junction_social", "rtp", "lane_relative")
    driving = BatchedDriving([spec, spec])
    driving.reset(seeds=[1, 2])
    assert driving.action_width == 2
    for _ in range(3):
        out = driving.step(np.zeros((len(driving.slots), 2), dtype=np.float32))
    assert np.isfinite(out.reward).all()
