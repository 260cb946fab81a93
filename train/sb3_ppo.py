"""PPO with Stable-Baselines3 on the simulator (``--lib sb3``): the same tasks, configs and outputs.

Every agent of every env copy is one VecEnv slot (``SmartsVecEnv``, parameter sharing); SB3's PPO
trains on it with ``MultiInputPolicy`` through its own ``learn()``. The run's contract (the
TensorBoard tags, ``last.pt`` after every batch, the periodic held-out evaluations that pick
``best.pt``: ``train.run``, shared by both trainers) comes in through an SB3 callback
(``RunCallback``), and the step budget through ``BudgetPPO``, whose last rollout takes only the
steps the run still needs. The policy is exported in the project's checkpoint format (tensors +
metadata, ``weights_only`` loadable) so evaluation and the benchmark load it like the torchrl
checkpoints (``agents.sb3_policy.SB3Policy``), with SB3's own save beside each
(``final_sb3.zip``, ...) for ``stable_baselines3.PPO.load``.
"""

from __future__ import annotations

import io
import time
import warnings
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
import torch
from stable_baselines3 import PPO
from stable_baselines3.common.callbacks import BaseCallback

from agents.checkpoint import CheckpointError, write_checkpoint, write_file_atomically
from agents.sb3_policy import SB3_FORMAT
from smarts.dynamics.pose_control_torch import resolve_device
from train.config import ACTION_SPACES, TrainConfig
from train.run import (
    BatchPlan,
    Progress,
    Run,
    check_resume,
    comms_dict,
    initial_log_std,
    interface_dict,
    lane_relative_dict,
    training_specs,
)

if TYPE_CHECKING:
    from smarts.env.sb3_vec_env import SmartsVecEnv


def make_vec_env(cfg: TrainConfig) -> "SmartsVecEnv":
    """``envs`` scenario copies as one ``SmartsVecEnv``, as the torchrl trainer builds them
    (``train.ppo.make_driving``): every copy in this process (``workers: 0``) or spread over
    ``workers`` processes sharing one buffer with this one; SUMO copies always in processes of
    their own."""
    from smarts.env.sb3_vec_env import SmartsVecEnv
    from train.ppo import env_options, training_seed

    return SmartsVecEnv(training_specs(cfg), workers=cfg.workers, seed=training_seed(cfg), normalize_actions=True,
                        **env_options(cfg))  # fmt: skip


class BudgetPPO(PPO):
    """SB3's PPO whose last rollout is cut to the steps the run still needs (``budget`` in env
    steps over all slots; its rollouts are otherwise ``n_steps`` per slot), so a run ends less
    than one step of every slot past ``total_steps``, as the torchrl trainer's does."""

    budget: int | None = None

    def collect_rollouts(self, env, callback, rollout_buffer, n_rollout_steps: int) -> bool:
        left = -(-(self.budget - self.num_timesteps) // env.num_envs) if self.budget is not None else n_rollout_steps
        if 0 < left < n_rollout_steps:
            self.n_steps = left  # a smaller buffer for the last rollout; train() reads self.rollout_buffer
            self.rollout_buffer = self.rollout_buffer_class(
                left, self.observation_space, self.action_space, device=self.device, gamma=self.gamma,
                gae_lambda=self.gae_lambda, n_envs=self.n_envs, **self.rollout_buffer_kwargs,
            )  # fmt: skip
            rollout_buffer, n_rollout_steps = self.rollout_buffer, left
        return super().collect_rollouts(env, callback, rollout_buffer, n_rollout_steps)


class GradNorm:
    """The policy's gradient norm before SB3 clips it (SB3 does not log it): each parameter's
    gradient adds its squared norm as backward finishes with it; ``take`` gives the mean norm of
    the minibatches since the last call."""

    def __init__(self, parameters):
        self.squares, self.norms = 0.0, []
        self.handles = [p.register_post_accumulate_grad_hook(self._add) for p in parameters if p.requires_grad]

    def _add(self, param: torch.Tensor) -> None:
        self.squares += float(param.grad.detach().pow(2).sum())

    def step(self, *_) -> None:
        """An optimiser step: one minibatch's norm is complete."""
        self.norms.append(self.squares**0.5)
        self.squares = 0.0

    def take(self) -> float:
        norms, self.norms = self.norms, []
        return float(np.mean(norms)) if norms else float("nan")


class RunCallback(BaseCallback):
    """The run's contract inside SB3's ``learn()``: after every update (seen when the next rollout
    starts, or when training ends), the batch's metrics to TensorBoard, ``last.pt``, the periodic
    held-out evaluation and ``best.pt`` (``Run.end_of_batch``), and the progress line."""

    def __init__(self, cfg: TrainConfig, run: Run, vec, grad: GradNorm, progress: Progress):
        super().__init__()
        self.cfg, self.run, self.vec, self.grad, self.progress = cfg, run, vec, grad, progress
        self.metrics: dict[str, float] = {}
        self.first_step = 0
        self.start = time.perf_counter()
        self.update_start: float | None = None
        self.batch_steps = 0
        self.rollout_from = 0

    def save(self, path: Path) -> Path:
        return save_sb3(path, self.model, self.vec, self.cfg, self.metrics)

    def _on_training_start(self) -> None:
        self.first_step = self.rollout_from = self.model.num_timesteps
        self.start = time.perf_counter()

    def _on_rollout_start(self) -> None:
        if self.update_start is not None:
            self._end_of_batch()
        self.rollout_from = self.model.num_timesteps
        self.model.ep_info_buffer.clear()  # this rollout's episodes

    def _on_step(self) -> bool:
        return True

    def _on_rollout_end(self) -> None:
        self.update_start = time.perf_counter()
        self.batch_steps = self.model.num_timesteps - self.rollout_from

    def _on_training_end(self) -> None:
        if self.update_start is not None:
            self._end_of_batch()

    def _end_of_batch(self) -> None:
        cfg, model = self.cfg, self.model
        logged = model.logger.name_to_value  # what SB3's train() recorded (no output formats: nothing is written)
        step = model.num_timesteps
        metrics = {
            "loss/objective": logged["train/policy_gradient_loss"],
            "loss/critic": cfg.critic_coeff * logged["train/value_loss"],
            "loss/entropy": cfg.entropy_coeff * logged["train/entropy_loss"],
            "policy/entropy": -logged["train/entropy_loss"],
            "policy/kl_approx": logged["train/approx_kl"],  # SB3's E[(r - 1) - log r]: never negative
            "policy/action_std": logged.get("train/std", float("nan")),
            "policy/clip_fraction": logged["train/clip_fraction"],
            "train/explained_variance": logged["train/explained_variance"],
            "train/grad_norm": self.grad.take(),
            "train/lr": logged["train/learning_rate"],
            "perf/env_steps_per_s": (step - self.first_step) / (time.perf_counter() - self.start),
            "perf/update_s": time.perf_counter() - self.update_start,
        }
        episodes = list(model.ep_info_buffer)
        if episodes:
            metrics["episode/return"] = float(np.mean([e["r"] for e in episodes]))
            metrics["episode/length"] = float(np.mean([e["l"] for e in episodes]))
        self.metrics = {k: float(v) for k, v in metrics.items()}
        self.update_start = None
        # TensorBoard, last.pt and, every eval_every steps, a held-out evaluation (best.pt).
        self.run.end_of_batch(step, self.batch_steps, self.metrics, self.save)
        self.progress.update(step, self.metrics)


def build_model(cfg: TrainConfig, vec: "SmartsVecEnv") -> BudgetPPO:
    """SB3's PPO on ``vec`` with every setting of the training config (a test reads them back):
    rollouts of ``frames_per_batch`` rounded up to whole steps of every slot, as torchrl's."""
    plan = BatchPlan.of(cfg.total_steps, cfg.frames_per_batch, vec.num_envs)
    device = resolve_device(cfg.device) or torch.device("cpu")
    with warnings.catch_warnings():
        # The last minibatch of a rollout may be smaller than the others (as in the torchrl trainer).
        warnings.filterwarnings("ignore", message="You have specified a mini-batch size")
        model = BudgetPPO(
            "MultiInputPolicy",
            vec,
            n_steps=plan.first_steps,  # per slot, per rollout
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
            stats_window_size=plan.first_steps * vec.num_envs,  # room for every episode that ends in a rollout
            seed=cfg.seed,
            device=device,
            verbose=0,
        )
    from train.ppo import training_seed

    vec.seed(training_seed(cfg))  # PPO(seed=...) seeded the env with the run seed: the training episodes keep theirs
    size = model.policy.log_std.numel()  # the same starting exploration as the torchrl trainer
    log_std = initial_log_std(cfg.init_log_std, size)
    with torch.no_grad():
        model.policy.log_std.copy_(torch.as_tensor(log_std, dtype=model.policy.log_std.dtype))
    return model


def train_sb3(cfg: TrainConfig, out: Path, progress: bool = True, resume: Path | None = None) -> Path:
    """Train, log and checkpoint under ``out`` as ``train.ppo.train`` does; returns the final
    checkpoint path. ``resume`` continues from an SB3 run's checkpoint (policy, optimiser, step
    count) up to ``total_steps``."""
    torch.set_num_threads(cfg.torch_threads)
    if cfg.init_from:
        raise ValueError("init_from: starting from another run's networks is for lib torchrl; SB3 runs resume only")
    if cfg.ray_address:
        raise ValueError("ray_address: Ray collectors are for lib torchrl; SB3 runs step their envs in processes")
    resolve_device(cfg.device)  # a GPU that is not there: refused before the run folder is made
    resolve_device(cfg.sim_device)
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
        model._n_updates = int(blob.get("n_updates", 0))  # SB3's own count of gradient steps, kept across resumes
    model.budget = cfg.total_steps
    grad = GradNorm(model.policy.parameters())
    model.policy.optimizer.register_step_post_hook(grad.step)
    bar = Progress(f"PPO (SB3) {cfg.task}", cfg.total_steps, model.num_timesteps, enabled=progress)
    callback = RunCallback(cfg, run, vec, grad, bar)
    try:
        # log_interval None: SB3's logger keeps what train() records for the callback and writes nothing.
        model.learn(cfg.total_steps - model.num_timesteps, callback=callback, log_interval=None,
                    reset_num_timesteps=False)  # fmt: skip
    except KeyboardInterrupt:
        bar.close()
        run.interrupted(model.num_timesteps, callback.save)  # interrupted.pt and interrupted_sb3.zip
        raise
    finally:
        bar.close()
        vec.close()
    return run.finish(model.num_timesteps, callback.metrics, callback.save, callback.start)


def save_sb3(path: Path, model, vec, cfg: TrainConfig, metrics: dict | None = None) -> Path:
    """The policy exported in the project's format (``weights_only`` loadable; what evaluation, the
    benchmark and ``--resume`` read) at ``path``, and SB3's own save beside it as ``<name>_sb3.zip``
    (for ``stable_baselines3.PPO.load``)."""
    spaces = vec.observation_space.spaces
    blob = {
        "format": SB3_FORMAT,
        "policy": {k: v.cpu() for k, v in model.policy.state_dict().items()},
        "optimizer": model.policy.optimizer.state_dict(),
        "observation": {k: list(s.shape) for k, s in spaces.items()},
        "interface": interface_dict(cfg),
        "lane_relative": lane_relative_dict(cfg),
        "comms": comms_dict(cfg),
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
