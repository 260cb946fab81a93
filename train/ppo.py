"""PPO on the simulator with TorchRL: collector, GAE and ClipPPOLoss (no hand-written PPO maths).

The whole algorithm in one readable loop:

1. ``envs`` copies of the task's training scenarios (every learning agent of every copy is one
   slot, all driven by one shared policy) run as one batched env, in ``workers`` processes when
   > 1; a ``Collector`` gathers ``frames_per_batch`` steps with the current stochastic policy.
   With ``ray_address``, each of the ``workers`` batches is stepped by its own collector running
   as a Ray actor instead.
2. The observations are flattened and normalised once for the whole update (``ValueInputs``).
3. ``epochs`` passes, each starting with torchrl's GAE (advantages and value targets per slot
   trajectory, with the critic as updated so far), then dropping the steps of slots that were
   waiting for their scenario copy to restart (``valid`` false), then minibatch updates of
   torchrl's ``ClipPPOLoss`` (clipped objective + value loss + entropy bonus, normalised
   advantages), Adam, gradient clipping; then the observation normaliser takes the batch's
   statistics for the next collection.
4. TensorBoard: episode return/length, losses, entropy, KL, learning rate, env steps/s; a checkpoint
   after every batch (``last.pt``) and on Ctrl-C. Every ``eval_every`` steps the task's benchmark
   suite runs on the checkpoint with held-out seeds; ``best.pt`` is the one with the highest
   S_bench. At the end ``final.pt`` is evaluated the same way.

The run folder, checkpoint set, TensorBoard tags, evaluations and summary are the ones every
trainer shares (``train.run``; ``train.sb3_ppo`` trains SB3's PPO under the same contract).
"""

from __future__ import annotations

import contextlib
import functools
import time
from pathlib import Path

import numpy as np
import torch
from tensordict.nn import TensorDictModule
from torch import nn
from torchrl.collectors import Collector
from torchrl.envs import RewardSum, TransformedEnv
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
from smarts.env.task_rewards import reward_factory
from smarts.dynamics.pose_control_torch import resolve_device
from smarts.env.torchrl_env import SmartsBatchedEnv
from train.config import ACTION_SPACES, TrainConfig
from train.run import TRAIN_SEED_BASE, Run, check_resume, interface_dict, lane_relative_dict, training_specs


def env_options(cfg: TrainConfig) -> dict:
    """What every training env copy gets besides its scenario: observation, task reward,
    lane-relative settings and where the simulation's torch stages run."""
    return {
        "observation": cfg.observation_interface(),
        "reward_factory": reward_factory(cfg.reward_weights()),
        "lane_relative": cfg.lane_relative_params(),
        "sim_device": cfg.device,
    }


def env_workers(cfg: TrainConfig) -> int:
    """``BatchedDriving``'s ``workers`` for the config: ``workers: 1`` steps the copies in this
    process (0 worker processes), N > 1 spreads them over N processes. Both backends build the same
    env (``TrainConfig.backend``); SUMO copies always get a worker process of their own."""
    return cfg.workers if cfg.workers > 1 else 0


def check_env_split(cfg: TrainConfig, specs: list) -> None:
    """Refuse, before anything is built or written, a ``device`` whose GPU is not there. (Any split
    of the copies over workers works: each worker process steps its share as one simulation, and
    SUMO copies run in processes of their own.)"""
    resolve_device(cfg.device)


def make_env(cfg: TrainConfig, specs: list | None = None) -> TransformedEnv:
    """``envs`` scenario copies (cycling through the task's scenarios; ``specs`` when already
    built) as one ``SmartsBatchedEnv`` whatever the backend: one simulation of every copy in this
    process, or spread over ``workers`` processes (``env_workers``)."""
    specs = training_specs(cfg) if specs is None else specs
    check_env_split(cfg, specs)
    env = TransformedEnv(SmartsBatchedEnv(specs, workers=env_workers(cfg), **env_options(cfg)), RewardSum())
    env.set_seed(TRAIN_SEED_BASE + cfg.seed * 1_000_003)
    return env


def transformed_batched_env(specs: list, seed: int, options: dict) -> TransformedEnv:
    """One batch of scenario copies with the episode statistics training reads; module-level so
    that ``functools.partial`` of it pickles to Ray actors."""
    env = TransformedEnv(SmartsBatchedEnv(specs, **options), RewardSum())
    env.set_seed(seed)
    return env


def ray_env_factories(cfg: TrainConfig) -> list:
    """Per Ray collector, a picklable factory of its share of the ``envs`` scenario copies, the
    same for both backends. Each share keeps its copies' numbers in the whole batch
    (``copy_ids``), so with the one training seed every copy plays the episodes it plays without
    Ray."""
    if cfg.envs % cfg.workers or cfg.frames_per_batch % cfg.workers:
        raise ValueError(f"with ray_address, envs ({cfg.envs}) and frames_per_batch ({cfg.frames_per_batch}) "
                         f"must be multiples of workers ({cfg.workers})")  # fmt: skip
    specs = training_specs(cfg)
    shares = [list(range(w, cfg.envs, cfg.workers)) for w in range(cfg.workers)]
    seed = TRAIN_SEED_BASE + cfg.seed * 1_000_003
    # Ray stacks the collectors' batches: pad every collector to the same number of slots.
    slots = max(sum(not a.is_social for i in share for a in specs[i].agents) for share in shares)
    return [functools.partial(transformed_batched_env, [specs[i] for i in share], seed,
                              {**env_options(cfg), "slots": slots, "copy_ids": share})
            for share in shares]  # fmt: skip


class RewardScaler:
    """Divides rewards by a running standard deviation of the discounted return (per slot), so the
    critic regresses targets of order one whatever the reward's scale (the usual PPO reward
    normalisation; the logged episode returns stay in the reward's own units)."""

    def __init__(self, gamma: float):
        self.gamma = gamma
        self.returns: torch.Tensor | None = None
        self.mean, self.var, self.count = 0.0, 1.0, 1e-4

    def __call__(self, data) -> None:
        reward = data["next", "reward"]  # [slots, time, 1]
        done = data["next", "done"].float()
        valid = data["valid"].float()
        if self.returns is None:
            self.returns = torch.zeros(reward.shape[0], 1)
        seen = []
        for t in range(reward.shape[1]):
            self.returns = self.returns * self.gamma * valid[:, t] + reward[:, t] * valid[:, t]
            seen.append(self.returns[valid[:, t] > 0])
            self.returns = self.returns * (1.0 - done[:, t])
        batch = torch.cat(seen) if seen else torch.zeros(0)
        if batch.numel() > 1:
            b_mean, b_var, n = float(batch.mean()), float(batch.var(unbiased=False)), batch.numel()
            delta, total = b_mean - self.mean, self.count + n
            self.mean += delta * n / total
            self.var = (self.var * self.count + b_var * n + delta**2 * self.count * n / total) / total
            self.count = total
        data["next", "reward"] = reward / max(self.var**0.5, 1e-4)


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
        self.last_mean: torch.Tensor | None = None
        """The mean of the last pass with gradients (the loss's own actor pass), for the action-bound
        penalty: it reuses that pass instead of running the actor again."""

    def forward(self, x: torch.Tensor):
        pre, std = self.actor(x)
        mean = scale_action(pre, self.low, self.high)
        if torch.is_grad_enabled():
            self.last_mean = mean
        return mean, std * 0.5 * (self.high - self.low)

    def take_last_mean(self) -> torch.Tensor:
        mean, self.last_mean = self.last_mean, None
        if mean is None:
            raise RuntimeError("the PPO loss did not run the actor with gradients before the action-bound penalty")
        return mean


def raw_features(layout: ObservationLayout, obs_spec) -> torch.Tensor:
    """1 for the flat inputs the normaliser must pass unchanged: masks and 0/1 flags (entries
    bounded to [0, 1], and the flag columns of ``lead`` and ``signal``)."""
    from smarts.sensors.observation import LEAD_FEATURE_NAMES

    flags = {"lead": ("present", "visible", "in_lane"), "signal": (0, 1, 2), "ahead": (0,)}
    parts = []
    for key, shape in zip(layout.keys, layout.shapes):
        size = int(np.prod(shape))
        spec = obs_spec[key]
        low, high = getattr(spec.space, "low", None), getattr(spec.space, "high", None)
        bounded01 = low is not None and bool((low == 0).all()) and bool((high == 1).all())
        mark = torch.full((size,), 1.0 if bounded01 else 0.0)
        if key == "lead":
            mark[[LEAD_FEATURE_NAMES.index(n) for n in flags["lead"]]] = 1.0
        elif key in ("signal", "ahead"):
            mark[list(flags[key])] = 1.0
        parts.append(mark)
    return torch.cat(parts)


def build_modules(env, cfg: TrainConfig):
    obs_spec = env.observation_spec["observation"]
    keys = tuple(sorted(obs_spec.keys()))
    batch_dims = len(env.batch_size)  # [slots] in front when the env is batched
    layout = ObservationLayout(keys, tuple(tuple(obs_spec[k].shape[batch_dims:]) for k in keys))
    action_spec = env.action_spec
    low = action_spec.space.low.reshape(-1, action_spec.shape[-1])[0]
    high = action_spec.space.high.reshape(-1, action_spec.shape[-1])[0]
    normalizer = ObsNormalizer(layout.size, clip=cfg.obs_clip, std_floor=cfg.obs_std_floor,
                               raw=raw_features(layout, obs_spec))  # fmt: skip
    size = action_spec.shape[-1]
    log_std = cfg.init_log_std if len(cfg.init_log_std) == size else cfg.init_log_std[:1] * size
    if len(cfg.init_log_std) not in (1, size):
        raise ValueError(f"init_log_std: expected 1 or {size} values (one per action component), got {cfg.init_log_std}")
    actor_net = Actor(layout.size, size, tuple(cfg.hidden), init_log_std=log_std)
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


FLAT_OBSERVATION = "flat_observation"
"""Key of the normalised flat observation the PPO update works on (written once per batch)."""


def update_modules(actor: ProbabilisticActor, critic: ValueOperator, action_spec) -> tuple[ProbabilisticActor, ValueOperator]:
    """The policy and critic as the update runs them: the same networks (shared parameters) read
    ``FLAT_OBSERVATION`` instead of flattening and normalising the observation on every call. The
    statistics stay fixed during an update, so once per batch (``ValueInputs``) gives the same inputs."""
    policy_head = next(m for m in actor.modules() if isinstance(m, _FlatNormalised)).head
    critic_head = next(m for m in critic.modules() if isinstance(m, _FlatNormalised)).head
    policy = TensorDictModule(policy_head, in_keys=[FLAT_OBSERVATION], out_keys=["loc", "scale"])
    loss_actor = ProbabilisticActor(policy, in_keys=["loc", "scale"], spec=action_spec,
                                    distribution_class=IndependentNormal, return_log_prob=True)  # fmt: skip
    return loss_actor, ValueOperator(critic_head, in_keys=[FLAT_OBSERVATION])


class ValueInputs:
    """The critic's inputs of a [slots, time] batch, prepared once per batch: the normalised flat
    observations (written into ``data`` as ``FLAT_OBSERVATION``, which the update's actor also
    reads) and the few next observations that are not the slot's following observation (ends of
    episodes, the last step of the batch). Every other next value is the following step's value,
    so each epoch's values cost one critic pass over the batch instead of two. ``raw`` keeps the
    flat observations before normalising, for the statistics update after the epochs."""

    @torch.no_grad()
    def __init__(self, data, layout: ObservationLayout, normalizer: ObsNormalizer):
        self.raw = layout.flatten({k: data["observation", k] for k in layout.keys})
        following = layout.flatten({k: data["next", "observation", k] for k in layout.keys})
        self.own = torch.ones(self.raw.shape[:2], dtype=torch.bool)
        self.own[:, :-1] = (following[:, :-1] != self.raw[:, 1:]).any(-1)
        self.own_next = normalizer(following[self.own])
        data[FLAT_OBSERVATION] = normalizer(self.raw)

    @torch.no_grad()
    def write_values(self, data, critic_net: nn.Module) -> None:
        """``state_value`` and ``("next", "state_value")`` of ``data`` with the critic as it is now."""
        value = critic_net(data[FLAT_OBSERVATION])
        next_value = torch.empty_like(value)
        next_value[:, :-1] = value[:, 1:]
        next_value[self.own] = critic_net(self.own_next)
        data["state_value"] = value
        data["next", "state_value"] = next_value


def action_bound_loss(mean: torch.Tensor, low: torch.Tensor, high: torch.Tensor) -> torch.Tensor:
    """Squared distance of the Gaussian's mean outside the action box. Beyond the box the simulator
    clips every sample to the same action, so PPO's gradient there is noise and the mean drifts
    away (and a lane change requested at +3 means the same as at +0.6); this keeps it in reach."""
    return ((mean - high).clamp(min=0.0) ** 2 + (low - mean).clamp(min=0.0) ** 2).sum(-1).mean()


def minibatches(data, size: int):
    """``data`` (a flat TensorDict) in random minibatches of ``size`` (the last one smaller), each
    step once: one permutation and one gather per minibatch."""
    order = torch.randperm(data.shape[0])
    for start in range(0, data.shape[0], size):
        yield data[order[start : start + size]]


def check_init_from(path: Path, cfg: TrainConfig) -> dict:
    """A checkpoint to start a new run from (fine-tuning, e.g. the platoon policy on the pybullet
    car): it must read the same observation and give commands of the same meaning (controller,
    command box), whatever action space drives the vehicle; checked before anything is built."""
    blob = load_checkpoint(path)
    mine = {
        "controller": cfg.controller,
        "observation interface": interface_dict(cfg),
        "hidden layers": list(cfg.hidden),
    }
    theirs = {
        "controller": blob["action"].get("controller", "direct"),
        "observation interface": blob.get("interface"),
        "hidden layers": list(blob["hidden"]),
    }
    for what, value in mine.items():
        if theirs[what] != value:
            raise CheckpointError(f"{path}: trained with {what} {theirs[what]!r}; this run uses {value!r}")
    if cfg.controller == "direct" and blob["action"]["space"] != ACTION_SPACES[cfg.action_space]:
        raise CheckpointError(
            f"{path}: direct actions of {blob['action']['space']!r} mean nothing in {ACTION_SPACES[cfg.action_space]!r}"
        )
    return blob


def build_learner(cfg: TrainConfig, actor, critic) -> tuple[GAE, ClipPPOLoss, torch.optim.Adam]:
    """torchrl's GAE and clipped PPO loss and the optimiser, with the config's settings. GAE reads
    the values ``ValueInputs.write_values`` writes."""
    advantage = GAE(gamma=cfg.gamma, lmbda=cfg.gae_lambda, value_network=None, average_gae=False)
    loss_module = ClipPPOLoss(actor, critic, clip_epsilon=cfg.clip_epsilon, entropy_coeff=cfg.entropy_coeff,
                              critic_coeff=cfg.critic_coeff, loss_critic_type="l2",
                              normalize_advantage=True)  # fmt: skip
    optimizer = torch.optim.Adam(loss_module.parameters(), lr=cfg.lr)
    return advantage, loss_module, optimizer


def train(cfg: TrainConfig, out: Path, progress: bool = True, resume: Path | None = None) -> Path:
    """Train, log and checkpoint under ``out``; returns the final checkpoint path. ``resume``
    continues from a checkpoint (networks, observation statistics, optimiser, step count) up to
    ``total_steps``."""
    from rich.progress import Progress

    torch.set_num_threads(cfg.torch_threads)
    blob = check_resume(resume, cfg) if resume is not None else None
    start_from = check_init_from(Path(cfg.init_from), cfg) if cfg.init_from else None
    if blob is not None and start_from is not None:
        raise ValueError("resume continues a run and init_from starts a new one from trained networks: give one")
    specs = None if cfg.ray_address else training_specs(cfg)
    if specs is not None:
        check_env_split(cfg, specs)
    torch.manual_seed(cfg.seed)
    np.random.seed(cfg.seed)
    run = Run(cfg, out, resume, progress=progress)  # the run folder (never another run's), config.json, TensorBoard
    scale_out = contextlib.ExitStack()
    if cfg.ray_address:
        from smarts.ray_session import ray_session

        factories = ray_env_factories(cfg)
        env = factories[0]()  # only for the specs the networks are built from
        scale_out.enter_context(ray_session(cfg.ray_address, num_cpus=max(2, cfg.workers)))
    else:
        env = make_env(cfg, specs)
    layout, normalizer, actor_net, critic_net, actor, critic, low, high = build_modules(env, cfg)
    advantage, loss_module, optimizer = build_learner(cfg, *update_modules(actor, critic, env.action_spec))
    head = next(m for m in actor.modules() if isinstance(m, _GaussianInActionUnits))
    scale_rewards = RewardScaler(cfg.gamma)
    bound_low, bound_high = torch.as_tensor(low), torch.as_tensor(high)
    step = 0
    if blob is not None:
        try:
            actor_net.load_state_dict(blob["actor"])
            critic_net.load_state_dict(blob["critic"])
            normalizer.load_state_dict(blob["normalizer"])
            if "optimizer" in blob:
                optimizer.load_state_dict(blob["optimizer"])
        except (RuntimeError, ValueError) as err:
            raise CheckpointError(f"{resume}: does not match this training setup ({err})") from None
        step = int(blob["step"])
    if start_from is not None:  # networks and statistics only: a fresh optimiser from step 0
        try:
            actor_net.load_state_dict(start_from["actor"])
            critic_net.load_state_dict(start_from["critic"])
            normalizer.load_state_dict(start_from["normalizer"])
        except (RuntimeError, ValueError) as err:
            raise CheckpointError(f"{cfg.init_from}: does not match this training setup ({err})") from None
    # A whole number of steps of every slot per batch (torchrl rounds up to it anyway).
    slots = int(np.prod(env.batch_size)) if not cfg.ray_address else 1
    frames = -(-cfg.frames_per_batch // slots) * slots
    remaining = -(-(cfg.total_steps - step) // frames) * frames  # whole batches (torchrl would round up too)
    if cfg.ray_address:
        env.close()
        collector = Collector(factories, actor, backend="ray", num_collectors=cfg.workers, sync=True,
                              frames_per_batch=frames, total_frames=remaining,
                              remote_configs={"num_cpus": 1})  # fmt: skip
        collector.update_policy_weights_()  # the actors start from these (possibly resumed) weights
    else:
        collector = Collector(env, actor, frames_per_batch=frames, total_frames=remaining,
                              auto_register_policy_transforms=False)
    metrics, start, first_step = {}, time.perf_counter(), step
    collecting_s, batch_end = 0.0, start  # time spent collecting (env steps and policy inference)

    def save(path: Path) -> Path:
        return save_checkpoint(path, actor=actor_net, critic=critic_net, normalizer=normalizer, layout=layout,
                               low=low, high=high, action_space=ACTION_SPACES[cfg.action_space],
                               controller=cfg.controller, interface=interface_dict(cfg),
                               lane_relative=lane_relative_dict(cfg),
                               config=cfg.model_dump(), step=step, metrics=metrics,
                               optimizer_state=optimizer.state_dict())  # fmt: skip

    try:
        with Progress(disable=not progress) as bar:
            task = bar.add_task(f"PPO {cfg.task}", total=cfg.total_steps)
            for data in collector:
                collect_time = time.perf_counter()
                collecting_s += collect_time - batch_end
                data = data.reshape(-1, data.shape[-1])  # [slots (of every collector), time]
                flat = data.reshape(-1)
                ended = flat["next", "done"].reshape(-1) & flat["valid"].reshape(-1)
                returns = flat["next", "episode_reward"].reshape(-1)[ended]  # in the reward's units
                lengths = flat["next", "agent_steps"].reshape(-1)[ended]
                if cfg.reward_scaling:
                    scale_rewards(data)
                # GAE on [slots, time], so advantages stop at each trajectory's end, once per epoch
                # with the critic as updated so far (once per batch learned markedly slower in short
                # runs); steps of waiting slots are then dropped and the minibatches mix the real steps.
                value_inputs = ValueInputs(data, layout, normalizer)
                valid = data["valid"].reshape(-1)
                stop = False
                for _ in range(cfg.epochs):
                    value_inputs.write_values(data, critic_net)
                    advantage(data)
                    learn = data.exclude("observation", "next").reshape(-1)[valid]  # what the loss reads
                    for batch in minibatches(learn, cfg.minibatch_size):
                        losses = loss_module(batch)
                        mean = head.take_last_mean()  # the actor's mean from the loss's own pass
                        if cfg.target_kl and float(losses.get("kl_approx", torch.tensor(0.0))) > cfg.target_kl:
                            stop = True  # the policy has moved far enough on this batch (as SB3 does)
                            break
                        total = losses["loss_objective"] + losses["loss_critic"] + losses["loss_entropy"]
                        if cfg.action_bound_coeff > 0:
                            total = total + cfg.action_bound_coeff * action_bound_loss(mean, bound_low, bound_high)
                        optimizer.zero_grad()
                        total.backward()
                        nn.utils.clip_grad_norm_(loss_module.parameters(), cfg.max_grad_norm)
                        optimizer.step()
                    if stop:
                        break
                # Refresh the observation statistics only now: during the update the policy must see
                # its inputs exactly as it did when it acted, or PPO's probability ratios are off.
                inputs = value_inputs.raw.reshape(-1, layout.size)[valid]
                clipped = normalizer.clipped_fraction(inputs)
                if cfg.obs_norm:
                    normalizer.update(inputs)
                collector.update_policy_weights_()
                step += data.numel()
                losses = losses.detach()
                metrics = {
                    "loss/objective": float(losses["loss_objective"]),
                    "loss/critic": float(losses["loss_critic"]),
                    "loss/entropy": float(losses["loss_entropy"]),
                    "policy/entropy": float(losses.get("entropy", torch.tensor(float("nan")))),
                    "policy/kl_approx": float(losses.get("kl_approx", torch.tensor(float("nan")))),
                    "policy/action_std": float(actor_net.log_std.detach().clamp(-3.0, 0.5).exp().mean()),
                    "obs/clipped_fraction": clipped,
                    "train/lr": optimizer.param_groups[0]["lr"],
                    "train/valid_fraction": float(inputs.shape[0] / max(flat.numel(), 1)),
                    "perf/env_steps_per_s": (step - first_step) / (time.perf_counter() - start),
                    "perf/update_s": time.perf_counter() - collect_time,
                    "perf/collect_steps_per_s": (step - first_step) / max(collecting_s, 1e-9),
                }
                if len(returns):
                    metrics["episode/return"] = float(returns.mean())
                    metrics["episode/length"] = float(lengths.float().mean())
                # TensorBoard, last.pt and, every eval_every steps, a held-out evaluation (best.pt).
                run.end_of_batch(step, data.numel(), metrics, save)
                batch_end = time.perf_counter()
                bar.update(task, completed=min(step, cfg.total_steps),
                           description=f"PPO {cfg.task} return {metrics.get('episode/return', float('nan')):.1f}")  # fmt: skip
    except KeyboardInterrupt:
        run.interrupted(step, save)  # interrupted.pt
        raise
    finally:
        collector.shutdown()
        env.close(raise_if_closed=False)  # the collector may have closed it already
        scale_out.close()
    return run.finish(step, metrics, save, start)  # final.pt, its evaluation, the summary
