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


def test_normaliser_passes_flags_raw_and_never_pins_a_feature_to_the_clip():
    """Masks and flags stay 0/1; a feature that is nearly constant in the statistics (a mask that is
    almost always 1, a lane width) is divided by at least the floor, so when it does change it
    does not jump to the clip."""
    from train.config import load_config
    from train.ppo import env_parts, make_env

    cfg = load_config("platoon", overrides={"envs": 4, "workers": 0})
    env = make_env(cfg)
    try:
        parts = env_parts(env, cfg)
        layout, normalizer = parts.layout, parts.normalizer
        rollout = env.rollout(60, break_when_any_done=False)
    finally:
        env.close()
    x = layout.flatten({k: rollout["observation", k].reshape(-1, *layout.shapes[i]) for i, k in enumerate(layout.keys)})
    normalizer.update(x)
    y = normalizer(x)
    raw = normalizer.raw > 0
    assert raw.sum() > 0 and torch.equal(y[:, raw], x[:, raw])  # flags untouched
    at_clip = (y[:, ~raw].abs() >= float(normalizer.clip_value) - 1e-6).float().mean(0)
    assert at_clip.max() < 0.05  # no input sits at the clip for more than a few samples
    flag_keys = {"neighbour_mask", "waypoint_mask", "events"}
    offset = 0
    for key, shape in zip(layout.keys, layout.shapes):
        size = int(np.prod(shape))
        if key in flag_keys:
            assert raw[offset : offset + size].all(), key
        offset += size
