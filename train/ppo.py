"""PPO on the simulator with TorchRL: collector, GAE and ClipPPOLoss (no hand-written PPO maths).

The whole algorithm in one readable loop:

1. ``envs`` copies of the task's training scenarios run as one batched env (in ``workers``
   processes when > 1); a ``Collector`` gathers ``frames_per_batch`` steps with the current
   stochastic policy. With ``ray_address``, each of the ``workers`` batches is stepped by its own
   collector running as a Ray actor instead.
2. GAE computes advantages and value targets.
3. ``epochs`` passes of minibatch updates of torchrl's ``ClipPPOLoss`` (clipped objective + value
   loss + entropy bonus, normalised advantages), Adam, gradient clipping; then the observation
   normaliser takes the batch's statistics for the next collection.
4. TensorBoard: episode return/length, losses, entropy, KL, learning rate, env steps/s; a checkpoint
   after every batch (``last.pt``) and on Ctrl-C; at the end, the benchmark suite of the task is
   run on the final checkpoint and its PR/RC/Humanness/MTE|SFD/S_bench logged.
"""

from __future__ import annotations

import contextlib
import dataclasses
import functools
import json
import time
from pathlib import Path

import numpy as np
import torch
from tensordict.nn import TensorDictModule
from torch import nn
from torchrl.collectors import Collector
from torchrl.data import LazyTensorStorage, ReplayBuffer
from torchrl.data.replay_buffers import SamplerWithoutReplacement
from torchrl.envs import Compose, ParallelEnv, RewardSum, StepCounter, TransformedEnv
from torchrl.modules import IndependentNormal, ProbabilisticActor, ValueOperator
from torchrl.objectives import ClipPPOLoss
from torchrl.objectives.value import GAE

from agents.ppo import (
    Actor,
    CheckpointError,
    Critic,
    ObservationLayout,
    ObsNormalizer,
    load_checkpoint,
    save_checkpoint,
    scale_action,
)
from smarts.env.torchrl_env import SmartsBatchedEnv
from train.config import ACTION_SPACES, TrainConfig

TASK_SUITE = {"platoon": "adaptive", "drive": "collaborative"}


def training_spec(name: str, action_space: str):
    """A scenario spec from ``suite:scenario`` or a library name, every agent on ``action_space``."""
    from smarts.benchmark.suites import load_suite
    from smarts.scenario import load_scenario

    if ":" in name:
        suite_name, scenario = name.split(":", 1)
        suite = load_suite(suite_name)
        matches = [s.spec for s in suite.scenarios if s.name == scenario]
        if not matches:
            raise ValueError(f"suite {suite_name!r} has no scenario {scenario!r}")
        spec = matches[0]
    else:
        spec = load_scenario(name)
    agents = [dataclasses.replace(a, action_space=ACTION_SPACES[action_space]) for a in spec.agents]
    return dataclasses.replace(spec, agents=agents)


def make_env(cfg: TrainConfig) -> TransformedEnv:
    """``envs`` scenario copies (cycling through the task's scenarios) stepped as one batched env in
    this process, or, with ``workers`` > 1, that many such batches in worker processes (needed for
    SUMO traffic: one SUMO per process)."""
    specs = [training_spec(cfg.scenarios[i % len(cfg.scenarios)], cfg.action_space) for i in range(cfg.envs)]
    if any(s.traffic is not None and s.traffic.engine == "sumo" for s in specs) and cfg.workers < cfg.envs:
        raise ValueError("SUMO scenarios run one per process: set workers equal to envs")
    if cfg.workers > 1:
        per = [specs[w :: cfg.workers] for w in range(cfg.workers)]
        base = ParallelEnv(cfg.workers, [functools.partial(SmartsBatchedEnv, p) for p in per], mp_start_method="spawn")
    else:
        base = SmartsBatchedEnv(specs)
    env = TransformedEnv(base, Compose(RewardSum(), StepCounter()))
    env.set_seed(cfg.seed)
    return env


def transformed_batched_env(specs: list, seed: int) -> TransformedEnv:
    """One batch of scenario copies with the episode statistics training reads; module-level so
    that ``functools.partial`` of it pickles to Ray actors."""
    env = TransformedEnv(SmartsBatchedEnv(specs), Compose(RewardSum(), StepCounter()))
    env.set_seed(seed)
    return env


def ray_env_factories(cfg: TrainConfig) -> list:
    """Per Ray collector, a picklable factory of its share of the ``envs`` scenario copies."""
    if cfg.envs % cfg.workers or cfg.frames_per_batch % cfg.workers:
        raise ValueError(f"with ray_address, envs ({cfg.envs}) and frames_per_batch ({cfg.frames_per_batch}) "
                         f"must be multiples of workers ({cfg.workers})")  # fmt: skip
    specs = [training_spec(cfg.scenarios[i % len(cfg.scenarios)], cfg.action_space) for i in range(cfg.envs)]
    per = [specs[w :: cfg.workers] for w in range(cfg.workers)]
    # Seeds spaced by the batch size, as the in-process batch seeds its copies seed, seed + 1, ...
    return [functools.partial(transformed_batched_env, p, cfg.seed + w * len(p)) for w, p in enumerate(per)]


class _FlatNormalised(nn.Module):
    """Concatenate the observation entries and normalise them, then apply ``head``."""

    def __init__(self, layout: ObservationLayout, normalizer: ObsNormalizer, head: nn.Module):
        super().__init__()
        self.layout, self.normalizer, self.head = layout, normalizer, head

    def forward(self, *parts: torch.Tensor):
        flat = self.layout.flatten(dict(zip(self.layout.keys, parts)))
        return self.head(self.normalizer(flat))


class _GaussianInActionUnits(nn.Module):
    """A Gaussian whose mean is the squashed actor output mapped onto [low, high] (the same mean
    ``PPOPolicy`` acts with) and whose spread is relative to the action range. Samples may leave
    the box; the action limits of the simulator clip them (no tanh Jacobian, so PPO's ratios and
    entropy stay well behaved)."""

    def __init__(self, actor: Actor, low: torch.Tensor, high: torch.Tensor):
        super().__init__()
        self.actor = actor
        self.register_buffer("low", low.float())
        self.register_buffer("high", high.float())

    def forward(self, x: torch.Tensor):
        pre, std = self.actor(x)
        return scale_action(pre, self.low, self.high), std * 0.5 * (self.high - self.low)


def build_modules(env, cfg: TrainConfig):
    obs_spec = env.observation_spec["observation"]
    keys = tuple(sorted(obs_spec.keys()))
    batch_dims = len(env.batch_size)  # [envs] in front when the env is batched
    layout = ObservationLayout(keys, tuple(tuple(obs_spec[k].shape[batch_dims:]) for k in keys))
    action_spec = env.action_spec
    low = action_spec.space.low.reshape(-1, action_spec.shape[-1])[0]
    high = action_spec.space.high.reshape(-1, action_spec.shape[-1])[0]
    normalizer = ObsNormalizer(layout.size)
    actor_net = Actor(layout.size, action_spec.shape[-1], tuple(cfg.hidden))
    critic_net = Critic(layout.size, tuple(cfg.hidden))
    in_keys = [("observation", k) for k in layout.keys]
    head = _GaussianInActionUnits(actor_net, low, high)
    policy = TensorDictModule(_FlatNormalised(layout, normalizer, head), in_keys=in_keys, out_keys=["loc", "scale"])
    actor = ProbabilisticActor(
        policy,
        in_keys=["loc", "scale"],
        spec=action_spec,
        distribution_class=IndependentNormal,
        return_log_prob=True,
    )
    critic = ValueOperator(_FlatNormalised(layout, normalizer, critic_net), in_keys=in_keys)
    return layout, normalizer, actor_net, critic_net, actor, critic, low.numpy(), high.numpy()


def train(cfg: TrainConfig, out: Path, progress: bool = True, resume: Path | None = None) -> Path:
    """Train, log and checkpoint under ``out``; returns the final checkpoint path. ``resume``
    continues from a checkpoint (networks, observation statistics, optimiser, step count) up to
    ``total_steps``."""
    from rich.progress import Progress
    from torch.utils.tensorboard import SummaryWriter

    torch.manual_seed(cfg.seed)
    np.random.seed(cfg.seed)
    out.mkdir(parents=True, exist_ok=True)
    (out / "config.json").write_text(json.dumps(dataclasses.asdict(cfg), indent=2))
    scale_out = contextlib.ExitStack()
    if cfg.ray_address:
        from smarts.ray_session import ray_session

        factories = ray_env_factories(cfg)
        env = factories[0]()  # only for the specs the networks are built from
        scale_out.enter_context(ray_session(cfg.ray_address, num_cpus=max(2, cfg.workers)))
    else:
        env = make_env(cfg)
    layout, normalizer, actor_net, critic_net, actor, critic, low, high = build_modules(env, cfg)
    advantage = GAE(gamma=cfg.gamma, lmbda=cfg.gae_lambda, value_network=critic, average_gae=True)
    loss_module = ClipPPOLoss(actor, critic, clip_epsilon=cfg.clip_epsilon, entropy_coeff=cfg.entropy_coeff,
                              critic_coeff=cfg.critic_coeff, loss_critic_type="smooth_l1",
                              normalize_advantage=True)  # fmt: skip
    optimizer = torch.optim.Adam(loss_module.parameters(), lr=cfg.lr)
    step = 0
    if resume is not None:
        blob = load_checkpoint(resume)
        try:
            actor_net.load_state_dict(blob["actor"])
            critic_net.load_state_dict(blob["critic"])
            normalizer.load_state_dict(blob["normalizer"])
            if "optimizer" in blob:
                optimizer.load_state_dict(blob["optimizer"])
        except (RuntimeError, ValueError) as err:
            raise CheckpointError(f"{resume}: does not match this training setup ({err})") from None
        step = int(blob["step"])
        if step >= cfg.total_steps:
            raise ValueError(f"{resume}: already at {step} steps; raise --total-steps to continue")
    frames = cfg.frames_per_batch
    if cfg.ray_address:
        env.close()
        collector = Collector(factories, actor, backend="ray", num_collectors=cfg.workers, sync=True,
                              frames_per_batch=frames, total_frames=cfg.total_steps - step,
                              remote_configs={"num_cpus": 1})  # fmt: skip
        collector.update_policy_weights_()  # the actors start from these (possibly resumed) weights
    else:
        collector = Collector(env, actor, frames_per_batch=frames, total_frames=cfg.total_steps - step,
                              auto_register_policy_transforms=False)
    buffer = ReplayBuffer(storage=LazyTensorStorage(frames), sampler=SamplerWithoutReplacement(),
                          batch_size=cfg.minibatch_size)  # fmt: skip
    writer = SummaryWriter(log_dir=str(out / "tensorboard"))
    metrics, start, best_return, first_step = {}, time.perf_counter(), -np.inf, step
    checkpoint = out / "last.pt"

    def save(path: Path) -> Path:
        return save_checkpoint(path, actor=actor_net, critic=critic_net, normalizer=normalizer, layout=layout,
                               low=low, high=high, action_space=ACTION_SPACES[cfg.action_space],
                               config=dataclasses.asdict(cfg), step=step, metrics=metrics,
                               optimizer_state=optimizer.state_dict())  # fmt: skip

    try:
        with Progress(disable=not progress) as bar:
            task = bar.add_task(f"PPO {cfg.task}", total=cfg.total_steps)
            for data in collector:
                collect_time = time.perf_counter()
                # GAE runs on [envs, time] so advantages stop at each env's trajectory end;
                # the minibatches then mix all envs' steps.
                for _ in range(cfg.epochs):
                    with torch.no_grad():
                        advantage(data)
                    buffer.extend(data.reshape(-1))
                    for batch in buffer:
                        losses = loss_module(batch)
                        total = losses["loss_objective"] + losses["loss_critic"] + losses["loss_entropy"]
                        optimizer.zero_grad()
                        total.backward()
                        nn.utils.clip_grad_norm_(loss_module.parameters(), cfg.max_grad_norm)
                        optimizer.step()
                # Refresh the observation statistics only now: during the update the policy must see
                # its inputs exactly as it did when it acted, or PPO's probability ratios are off.
                data = data.reshape(-1)
                normalizer.update(layout.flatten({k: data["observation", k] for k in layout.keys}))
                collector.update_policy_weights_()
                step += data.numel()
                done = data["next", "done"].reshape(-1)
                returns = data["next", "episode_reward"].reshape(-1)[done]
                lengths = data["next", "step_count"].reshape(-1)[done].float()
                losses = losses.detach()
                metrics = {
                    "loss/objective": float(losses["loss_objective"]),
                    "loss/critic": float(losses["loss_critic"]),
                    "loss/entropy": float(losses["loss_entropy"]),
                    "policy/entropy": float(losses.get("entropy", torch.tensor(float("nan")))),
                    "policy/kl_approx": float(losses.get("kl_approx", torch.tensor(float("nan")))),
                    "train/lr": optimizer.param_groups[0]["lr"],
                    "perf/env_steps_per_s": (step - first_step) / (time.perf_counter() - start),
                    "perf/update_s": time.perf_counter() - collect_time,
                }
                if len(returns):
                    metrics["episode/return"] = float(returns.mean())
                    metrics["episode/length"] = float(lengths.mean())
                for name, value in metrics.items():
                    if np.isfinite(value):
                        writer.add_scalar(name, value, step)
                save(checkpoint)
                if metrics.get("episode/return", -np.inf) > best_return:  # by training return
                    best_return = metrics["episode/return"]
                    save(out / "best.pt")
                if cfg.eval_every and cfg.eval_episodes and step // cfg.eval_every > (step - data.numel()) // cfg.eval_every:
                    evaluate_into(checkpoint, cfg, out / f"eval_{step}", writer, step)
                bar.update(task, completed=min(step, cfg.total_steps),
                           description=f"PPO {cfg.task} return {metrics.get('episode/return', float('nan')):.1f}")  # fmt: skip
    except KeyboardInterrupt:
        save(out / "interrupted.pt")
        print(f"interrupted at {step} steps; checkpoint saved to {out / 'interrupted.pt'}")
        raise
    finally:
        collector.shutdown()
        env.close(raise_if_closed=False)  # the collector may have closed it already
        writer.flush()
        scale_out.close()
    final = save(out / "final.pt")
    if cfg.eval_episodes > 0:
        metrics.update({f"eval/{k}": v for k, v in evaluate_into(final, cfg, out / "eval", writer, step).items()})
    writer.close()
    print(json.dumps({"steps": step, "wall_s": round(time.perf_counter() - start, 1), **metrics}, indent=2))
    return final


def evaluate_into(checkpoint: Path, cfg: TrainConfig, out: Path, writer, step: int) -> dict:
    """Run the task's benchmark suite on ``checkpoint`` (report under ``out``) and log its metrics
    and a few evaluation trajectory figures to TensorBoard."""
    from PIL import Image

    from smarts.benchmark.report import write_report
    from smarts.benchmark.runner import plan_jobs, run_jobs
    from smarts.benchmark.suites import load_suite

    suite = load_suite(TASK_SUITE[cfg.task])
    frozen = out / "policy.pt"  # the runner reads the file later: keep this step's weights
    out.mkdir(parents=True, exist_ok=True)
    frozen.write_bytes(Path(checkpoint).read_bytes())
    jobs = plan_jobs([str(frozen)], suite, cfg.eval_episodes, out)
    results = run_jobs(jobs, workers=2, progress=False)
    write_report(out, suite, [str(frozen)], results)
    scores = json.loads((out / "results.json").read_text())["agents"][str(frozen)]["scores"]
    overall = scores["overall"] if scores else {}
    for name, value in overall.items():
        writer.add_scalar(f"eval/{name}", value, step)
    for figure in sorted((out / "plots").glob("trajectories_*.png"))[:3]:
        image = np.asarray(Image.open(figure).convert("RGB"))
        writer.add_image(f"eval_trajectories/{figure.stem[len('trajectories_'):]}", image, step, dataformats="HWC")
    return overall
