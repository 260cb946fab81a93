"""PPO checkpoints: round trip, weights_only loading, clear errors for bad files."""

import gymnasium
import numpy as np
import pytest
import torch

import smarts.env  # noqa: F401
from agents.ppo import Actor, CheckpointError, Critic, ObservationLayout, ObsNormalizer, PPOPolicy, save_checkpoint


def _policy_parts():
    env = gymnasium.make("smarts/Driving-v0", scenario="straight_2lane_cruise")
    layout = ObservationLayout.from_space(env.observation_space)
    actor, critic, norm = Actor(layout.size, 3, (16, 16)), Critic(layout.size, (16, 16)), ObsNormalizer(layout.size)
    low, high = env.action_space.low, env.action_space.high
    return env, layout, actor, critic, norm, low, high


def test_round_trip_acts_identically(tmp_path):
    env, layout, actor, critic, norm, low, high = _policy_parts()
    obs, _ = env.reset(seed=0)
    norm.update(layout.flatten({k: v[None] for k, v in obs.items()}) + 1.0)
    path = save_checkpoint(tmp_path / "p.pt", actor=actor, critic=critic, normalizer=norm, layout=layout, low=low,
                           high=high, action_space="relative_target_pose", config={"hidden": [16, 16]}, step=7,
                           metrics={"return": 1.5})  # fmt: skip
    policy = PPOPolicy.load(path)
    policy.check_space(env.observation_space)
    batch = {k: v[None] for k, v in obs.items()}
    action = policy.act(batch)
    assert action.shape == (1, 3) and env.action_space.contains(action[0].astype(np.float32))
    expected = actor(norm(layout.flatten(batch)))[0].detach().numpy()
    np.testing.assert_allclose(action, np.clip(low + (expected + 1) * 0.5 * (high - low), low, high), rtol=1e-5)
    blob = torch.load(path, weights_only=True)  # loads without executing code
    assert blob["step"] == 7 and blob["metrics"]["return"] == 1.5


def test_corrupted_foreign_and_mismatched_files_are_clear_errors(tmp_path):
    env, layout, actor, critic, norm, low, high = _policy_parts()
    bad = tmp_path / "bad.pt"
    bad.write_bytes(b"not a checkpoint")
    with pytest.raises(CheckpointError, match="bad.pt: not a readable checkpoint"):
        PPOPolicy.load(bad)
    other = tmp_path / "other.pt"
    torch.save({"weights": torch.zeros(3)}, other)
    with pytest.raises(CheckpointError, match="expected a smarts-ppo-v1 checkpoint"):
        PPOPolicy.load(other)
    with pytest.raises(CheckpointError, match="no such checkpoint"):
        PPOPolicy.load(tmp_path / "missing.pt")
    path = save_checkpoint(tmp_path / "p.pt", actor=actor, critic=critic, normalizer=norm, layout=layout, low=low,
                           high=high, action_space="relative_target_pose", config={"hidden": [32, 32]}, step=0,
                           metrics={})  # fmt: skip
    with pytest.raises(CheckpointError, match="weights do not match"):
        PPOPolicy.load(path)  # the recorded hidden sizes disagree with the saved weights
    save_checkpoint(tmp_path / "q.pt", actor=actor, critic=critic, normalizer=norm, layout=layout, low=low, high=high,
                    action_space="relative_target_pose", config={"hidden": [16, 16]}, step=0, metrics={})  # fmt: skip
    policy = PPOPolicy.load(tmp_path / "q.pt")
    space = gymnasium.spaces.Dict({k: v for k, v in env.observation_space.spaces.items() if k != "goal"})
    with pytest.raises(CheckpointError, match="observation 'goal'"):
        policy.check_space(space)
