"""PPO with Stable-Baselines3 on the simulator (``--lib sb3``): the same tasks, configs and outputs.

Every agent of every env copy is one VecEnv slot (``SmartsVecEnv``, parameter sharing); SB3's PPO
trains on it unchanged with ``MultiInputPolicy``. The policy is exported in the project's
checkpoint format (tensors + metadata, ``weights_only`` loadable) so evaluation and the benchmark
load it like the torchrl checkpoints (``agents.sb3_policy.SB3Policy``).
"""

from __future__ import annotations

import dataclasses
import json
import time
from pathlib import Path

import numpy as np
import torch

from agents.sb3_policy import SB3_FORMAT
from train.config import ACTION_SPACES, TrainConfig


def make_vec_env(cfg: TrainConfig):
    import functools

    from smarts.env import DrivingParallelEnv
    from smarts.env.sb3_vec_env import SmartsVecEnv
    from smarts.env.task_rewards import TaskReward
    from train.ppo import TRAIN_SEED_BASE, training_specs

    interface, weights, lane = cfg.observation_interface(), cfg.reward_weights(), cfg.lane_relative_params()
    factories = [
        functools.partial(DrivingParallelEnv, spec, observation=interface, reward=TaskReward(weights), lane_relative=lane)
        for spec in training_specs(cfg)
    ]  # every learning agent of every copy is one slot
    return SmartsVecEnv(factories, seed=TRAIN_SEED_BASE + cfg.seed * 1_000_003, normalize_actions=True,
                        processes=cfg.workers > 1)  # fmt: skip


def train_sb3(cfg: TrainConfig, out: Path, progress: bool = True) -> Path:
    from stable_baselines3 import PPO

    torch.set_num_threads(cfg.torch_threads)
    out.mkdir(parents=True, exist_ok=True)
    (out / "config.json").write_text(json.dumps(dataclasses.asdict(cfg), indent=2))
    vec = make_vec_env(cfg)
    model = PPO(
        "MultiInputPolicy",
        vec,
        n_steps=max(cfg.frames_per_batch // vec.num_envs, 8),
        batch_size=cfg.minibatch_size,
        n_epochs=cfg.epochs,
        learning_rate=cfg.lr,
        gamma=cfg.gamma,
        gae_lambda=cfg.gae_lambda,
        clip_range=cfg.clip_epsilon,
        ent_coef=cfg.entropy_coeff,
        vf_coef=cfg.critic_coeff,
        max_grad_norm=cfg.max_grad_norm,
        policy_kwargs={"net_arch": list(cfg.hidden)},
        tensorboard_log=str(out / "tensorboard"),
        seed=cfg.seed,
        device="cpu",
        verbose=0,
    )
    start = time.perf_counter()
    try:
        model.learn(total_timesteps=cfg.total_steps, progress_bar=progress, tb_log_name="sb3")
    except KeyboardInterrupt:
        save_sb3(out / "interrupted.pt", model, vec, cfg)
        raise
    finally:
        vec.close()
    final = save_sb3(out / "final.pt", model, vec, cfg)
    if cfg.eval_episodes > 0:
        from torch.utils.tensorboard import SummaryWriter

        from train.ppo import evaluate_into

        with SummaryWriter(log_dir=str(out / "tensorboard" / "eval")) as writer:
            evaluate_into(final, cfg, out / "eval", writer, int(model.num_timesteps))
    rewards = [e["r"] for e in model.ep_info_buffer]
    summary = {"steps": int(model.num_timesteps), "wall_s": round(time.perf_counter() - start, 1),
               "env_steps_per_s": model.num_timesteps / (time.perf_counter() - start),
               "episode/return": float(np.mean(rewards)) if rewards else float("nan")}  # fmt: skip
    print(json.dumps(summary, indent=2))
    return final


def save_sb3(path: Path, model, vec, cfg: TrainConfig) -> Path:
    spaces = vec.observation_space.spaces
    blob = {
        "format": SB3_FORMAT,
        "policy": model.policy.state_dict(),
        "observation": {k: list(s.shape) for k, s in spaces.items()},
        "interface": _interface_dict(cfg),
        "lane_relative": dataclasses.asdict(cfg.lane_relative_params()) if cfg.controller == "lane_relative" else None,
        "action": {
            "space": ACTION_SPACES[cfg.action_space],
            "controller": cfg.controller,
            "low": vec._agent_action_space.low.tolist(),
            "high": vec._agent_action_space.high.tolist(),
        },
        "net_arch": list(cfg.hidden),
        "config": dataclasses.asdict(cfg),
        "step": int(model.num_timesteps),
    }
    tmp = path.with_name(path.name + ".tmp")
    torch.save(blob, tmp)
    tmp.replace(path)
    return path


def _interface_dict(cfg: TrainConfig) -> dict:
    from smarts.sensors.interface import interface_to_dict

    return interface_to_dict(cfg.observation_interface())
