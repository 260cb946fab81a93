"""PPO with Stable-Baselines3 on the simulator (``--lib sb3``): the same tasks, configs and outputs.

Every agent of every env copy is one VecEnv slot (``SmartsVecEnv``, parameter sharing); SB3's PPO
trains on it unchanged with ``MultiInputPolicy``; the loop below is SB3's own ``learn()`` written
out, so that every rollout ends like a torchrl batch: the run's TensorBoard tags, ``last.pt`` and
the periodic held-out evaluations that pick ``best.pt`` (``train.run``, shared by both trainers).
The policy is exported in the project's checkpoint format (tensors + metadata, ``weights_only``
loadable) so evaluation and the benchmark load it like the torchrl checkpoints
(``agents.sb3_policy.SB3Policy``), with SB3's own save beside each (``final_sb3.zip``, ...) for
``stable_baselines3.PPO.load``.
"""

from __future__ import annotations

import io
import time
from pathlib import Path

from typing import TYPE_CHECKING

import numpy as np
import torch

from agents.checkpoint import CheckpointError, write_checkpoint, write_file_atomically
from agents.sb3_policy import SB3_FORMAT
from smarts.dynamics.pose_control_torch import resolve_device
from train.config import ACTION_SPACES, TrainConfig
from train.run import TRAIN_SEED_BASE, Run, check_resume, interface_dict, lane_relative_dict, training_specs

if TYPE_CHECKING:
    from stable_baselines3 import PPO

    from smarts.env.sb3_vec_env import SmartsVecEnv


TRAINING_SEED_OFFSET = 1_000_003
"""Training seeds of run seed ``s`` start at ``TRAIN_SEED_BASE + s * TRAINING_SEED_OFFSET`` (as torchrl's)."""


def training_seed(cfg: TrainConfig) -> int:
    """The seed of the training episodes (copy ``i`` then counts up from ``+ i * 100_003``)."""
    return TRAIN_SEED_BASE + cfg.seed * TRAINING_SEED_OFFSET


def make_vec_env(cfg: TrainConfig) -> "SmartsVecEnv":
    """``envs`` scenario copies as one ``SmartsVecEnv`` whatever the backend, as the torchrl
    trainer builds them (``train.ppo.make_env``): one simulation of every copy in this process, or
    spread over ``workers`` processes; SUMO copies always in processes of their own."""
    from smarts.env.sb3_vec_env import SmartsVecEnv
    from smarts.env.task_rewards import reward_factory

    workers = cfg.workers if cfg.workers > 1 else 0  # workers: 1 is this process (as train.ppo.env_workers)
    return SmartsVecEnv(training_specs(cfg), observation=cfg.observation_interface(),
                        reward_factory=reward_factory(cfg.reward_weights()), lane_relative=cfg.lane_relative_params(),
                        sim_device=cfg.device, workers=workers, seed=training_seed(cfg),
                        normalize_actions=True)  # fmt: skip


def build_model(cfg: TrainConfig, vec: "SmartsVecEnv") -> "PPO":
    """SB3's PPO on ``vec`` with every setting of the training config (a test reads them back)."""
    from stable_baselines3 import PPO

    n_steps = max(cfg.frames_per_batch // vec.num_envs, 8)  # per slot, per rollout
    model = PPO(
        "MultiInputPolicy",
        vec,
        n_steps=n_steps,
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
        target_kl=cfg.target_kl or None,  # SB3 stops a rollout's epochs at 1.5 x this approximate KL
        stats_window_size=n_steps * vec.num_envs,  # room for every episode that ends in a rollout
        seed=cfg.seed,
        device="cpu",
        verbose=0,
    )
    vec.seed(training_seed(cfg))  # PPO(seed=...) seeded the env with the run seed: the training episodes keep theirs
    size = model.policy.log_std.numel()  # the same starting exploration as the torchrl trainer
    if len(cfg.init_log_std) not in (1, size):
        raise ValueError(f"init_log_std: expected 1 or {size} values (one per action component), got {cfg.init_log_std}")
    with torch.no_grad():
        model.policy.log_std.copy_(torch.as_tensor(cfg.init_log_std, dtype=model.policy.log_std.dtype).expand(size))
    return model


def train_sb3(cfg: TrainConfig, out: Path, progress: bool = True, resume: Path | None = None) -> Path:
    """Train, log and checkpoint under ``out`` as ``train.ppo.train`` does; returns the final
    checkpoint path. ``resume`` continues from an SB3 run's checkpoint (policy, optimiser, step
    count) up to ``total_steps``."""
    from rich.progress import Progress

    torch.set_num_threads(cfg.torch_threads)
    if cfg.init_from:
        raise ValueError("init_from: starting from another run's networks is for lib torchrl; SB3 runs resume only")
    if cfg.ray_address:
        raise ValueError("ray_address: Ray collectors are for lib torchrl; SB3 runs step their envs in processes")
    resolve_device(cfg.device)  # a GPU that is not there: refused before the run folder is made
    blob = check_resume(resume, cfg) if resume is not None else None
    run = Run(cfg, out, resume, progress=progress)  # the run folder (never another run's), config.json, TensorBoard
    vec = make_vec_env(cfg)
    try:
        model = build_model(cfg, vec)
    except ValueError:
        vec.close()
        raise
    if blob is not None:
        try:
            model.policy.load_state_dict(blob["policy"])
            if "optimizer" in blob:
                model.policy.optimizer.load_state_dict(blob["optimizer"])
        except (RuntimeError, ValueError, KeyError) as err:
            vec.close()
            raise CheckpointError(f"{resume}: does not match this training setup ({err})") from None
        model.num_timesteps = int(blob["step"])
        model._n_updates = int(blob.get("n_updates", 0))
    # SB3's own learn() loop, written out so that every rollout ends with the run's logging,
    # checkpoints and evaluations (its logger has no outputs: the values are read back from it).
    total, callback = model._setup_learn(cfg.total_steps - model.num_timesteps, reset_num_timesteps=False)
    callback.on_training_start(locals(), globals())
    step = model.num_timesteps
    metrics, start, first_step = {}, time.perf_counter(), step

    def save(path: Path) -> Path:
        return save_sb3(path, model, vec, cfg, metrics)

    try:
        with Progress(disable=not progress) as bar:
            task = bar.add_task(f"PPO (SB3) {cfg.task}", total=cfg.total_steps)
            while model.num_timesteps < total:
                model.ep_info_buffer.clear()  # this rollout's episodes
                model.collect_rollouts(vec, callback, model.rollout_buffer, n_rollout_steps=model.n_steps)
                update_start = time.perf_counter()
                model._update_current_progress_remaining(model.num_timesteps, total)
                model.train()  # GAE was computed at the rollout's end; epochs of clipped-PPO minibatches
                step = model.num_timesteps
                logged = dict(model.logger.name_to_value)
                model.logger.dump(step)  # (clears it)
                metrics = {
                    "loss/objective": logged["train/policy_gradient_loss"],
                    "loss/critic": cfg.critic_coeff * logged["train/value_loss"],
                    "loss/entropy": cfg.entropy_coeff * logged["train/entropy_loss"],
                    "policy/entropy": -logged["train/entropy_loss"],
                    "policy/kl_approx": logged["train/approx_kl"],
                    "policy/action_std": logged.get("train/std", float("nan")),
                    "policy/clip_fraction": logged["train/clip_fraction"],
                    "train/explained_variance": logged["train/explained_variance"],
                    "train/lr": logged["train/learning_rate"],
                    "perf/env_steps_per_s": (step - first_step) / (time.perf_counter() - start),
                    "perf/update_s": time.perf_counter() - update_start,
                }
                episodes = list(model.ep_info_buffer)
                if episodes:
                    metrics["episode/return"] = float(np.mean([e["r"] for e in episodes]))
                    metrics["episode/length"] = float(np.mean([e["l"] for e in episodes]))
                metrics = {k: float(v) for k, v in metrics.items()}
                # TensorBoard, last.pt and, every eval_every steps, a held-out evaluation (best.pt).
                run.end_of_batch(step, model.n_steps * vec.num_envs, metrics, save)
                bar.update(task, completed=min(step, cfg.total_steps),
                           description=f"PPO (SB3) {cfg.task} return {metrics.get('episode/return', float('nan')):.1f}")  # fmt: skip
    except KeyboardInterrupt:
        run.interrupted(step, save)  # interrupted.pt and interrupted_sb3.zip
        raise
    finally:
        vec.close()
    return run.finish(step, metrics, save, start)  # final.pt, its evaluation, the summary


def save_sb3(path: Path, model, vec, cfg: TrainConfig, metrics: dict | None = None) -> Path:
    """The policy exported in the project's format (``weights_only`` loadable; what evaluation, the
    benchmark and ``--resume`` read) at ``path``, and SB3's own save beside it as ``<name>_sb3.zip``
    (for ``stable_baselines3.PPO.load``)."""
    spaces = vec.observation_space.spaces
    blob = {
        "format": SB3_FORMAT,
        "policy": model.policy.state_dict(),
        "optimizer": model.policy.optimizer.state_dict(),
        "observation": {k: list(s.shape) for k, s in spaces.items()},
        "interface": interface_dict(cfg),
        "lane_relative": lane_relative_dict(cfg),
        "action": {
            "space": ACTION_SPACES[cfg.action_space],
            "controller": cfg.controller,
            "low": vec._agent_action_space.low.tolist(),
            "high": vec._agent_action_space.high.tolist(),
        },
        "net_arch": list(cfg.hidden),
        "config": cfg.model_dump(),
        "step": int(model.num_timesteps),
        "n_updates": int(model._n_updates),
        "metrics": {k: float(v) for k, v in (metrics or {}).items()},
    }
    path = write_checkpoint(blob, path)
    buffer = io.BytesIO()  # SB3's own save, written the same way (a failed write leaves the old one)
    model.save(buffer)
    write_file_atomically(path.with_name(f"{path.stem}_sb3.zip"), buffer.getbuffer(), "SB3 save")
    return path
