"""SmartsBatchedEnv: every learning agent of every scenario copy is a slot of one TorchRL env."""

import numpy as np
import pytest
import torch
from torchrl.envs.utils import check_env_specs

from smarts.core.errors import ActionError
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


def test_scenarios_must_share_spaces():
    other = make_spec([agent(offset=10.0, speed=10.0, action_space="continuous")])
    with pytest.raises(ValueError, match="observation or action space differs"):
        SmartsBatchedEnv([_specs()[0], other])


def test_a_bad_action_in_one_copy_steps_no_copy():
    env = SmartsBatchedEnv(_specs())
    env.set_seed(0)
    td = env.reset()
    td = _one_metre_per_step(td)
    td["action"][2, 1] = float("nan")  # copy 1, agent_1
    with pytest.raises(ActionError, match=r"env copy 1 \(test-scenario\): agent_1: relative_target_pose action component dy is nan"):
        env.step(td)
    assert [e.sim.step_count for e in env.envs] == [0, 0]
    td = _one_metre_per_step(env.reset())
    env.step(td)
    assert [e.sim.step_count for e in env.envs] == [1, 1]
