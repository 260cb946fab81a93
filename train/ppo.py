"""PPO on the simulator with TorchRL's loss and advantage (no hand-written PPO maths).

The whole algorithm is one readable loop (``train``, at the end of this file, with the update in
``Learner.update``):

1. ``envs`` copies of the task's training scenarios (every learning agent of every copy is one
   slot, all driven by one shared policy) run as one ``BatchedDriving``, in ``workers``
   processes over one shared-memory buffer (0: in this process). ``SlotCollector`` steps it for
   a batch of about ``frames_per_batch`` slot-steps, acting with a copy of the policy on the flat
   observation buffer (one normalise-and-act pass per step, no TensorDict per step); with two or
   more workers it acts for one half of the workers' copies while the other half steps.
2. ``overlap``: while the learner updates on one batch, the collector gathers the next with the
   policy of the update before (one update behind; PPO's probability ratio is taken against the
   policy that acted, so it corrects for that). Collection and update then share the machine's
   cores instead of taking turns.
3. ``Learner.update``: the observations are normalised once per batch; ``epochs`` passes, each
   starting with torchrl's GAE (advantages and value targets per slot trajectory, with the critic
   as updated so far), then dropping the steps of slots that were waiting for their scenario copy
   to restart, then random minibatches through torchrl's ``ClipPPOLoss`` (clipped objective +
   value loss + entropy bonus, normalised advantages), Adam, gradient clipping; then
   the observation normaliser takes the batch's statistics for the next collection.
4. TensorBoard: episode return/length, losses, entropy, KL, clip fraction, explained variance,
   gradient norm, learning rate, env steps/s; a checkpoint after every batch (``last.pt``) and on
   Ctrl-C. Every ``eval_every`` steps the task's benchmark suite runs on the checkpoint with
   held-out seeds; ``best.pt`` is the one with the highest S_bench. At the end ``final.pt`` is
   evaluated the same way.

``device`` is where the learner runs (inference and updates; ``cuda`` for a GPU), the
simulations stay on the CPU workers. With ``ray_address``, each of the ``workers`` batches is
stepped by torchrl's ``Collector`` running as a Ray actor instead (``RayCollection``); the
learner is the same.

The run folder, checkpoint set, TensorBoard tags, evaluations and summary are the ones every
trainer shares (``train.run``; ``train.sb3_ppo`` trains SB3's PPO under the same contract).
"""

from __future__ import annotations

import contextlib
import functools
import threading
import time
import warnings
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from pathlib import Path

import gymnasium as gym
import numpy as np
import torch
from tensordict import TensorDict
from tensordict.nn import TensorDictModule
from torch import nn
from torchrl.envs import RewardSum, TransformedEnv
from torchrl.modules import IndependentNormal, ProbabilisticActor, ValueOperator
from torchrl.objectives import ClipPPOLoss
from torchrl.objectives.value.functional import vec_generalized_advantage_estimate

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
from smarts.dynamics.pose_control_torch import resolve_device
from smarts.env.task_rewards import reward_factory
from train.config import ACTION_SPACES, TrainConfig
from train.run import (
    TRAIN_SEED_BASE,
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

TRAINING_SEED_OFFSET = 1_000_003
"""Training seeds of run seed ``s`` start at ``TRAIN_SEED_BASE + s * TRAINING_SEED_OFFSET``."""


def training_seed(cfg: TrainConfig) -> int:
    """The seed of the training episodes (copy ``i`` then counts up from ``+ i * 100_003``)."""
    return TRAIN_SEED_BASE + cfg.seed * TRAINING_SEED_OFFSET


def env_options(cfg: TrainConfig) -> dict:
    """What every training env copy gets besides its scenario: observation, task reward,
    lane-relative settings and where the simulation's torch stages run."""
    return {
        "observation": cfg.observation_interface(),
        "reward_factory": reward_factory(cfg.reward_weights()),
        "lane_relative": cfg.lane_relative_params(),
        "sim_device": cfg.sim_device,
    }


def learner_device(cfg: TrainConfig) -> torch.device:
    """The torch device of inference and updates: ``cpu`` (and ``torch-cpu``, the same path with
    explicit transfers, for tests without a GPU) or the named GPU; refused when it is not there."""
    return resolve_device(cfg.device) or torch.device("cpu")


def check_devices(cfg: TrainConfig) -> None:
    """Refuse, before anything is built or written, a ``device`` or ``sim_device`` whose GPU is
    not there."""
    resolve_device(cfg.device)
    resolve_device(cfg.sim_device)


def make_driving(cfg: TrainConfig, specs: list | None = None):
    """``envs`` scenario copies (cycling through the task's scenarios; ``specs`` when already
    built) as one ``BatchedDriving``: every copy in this process (``workers: 0``) or spread over
    ``workers`` processes that share one buffer with this one; SUMO copies always in processes of
    their own."""
    from smarts.env.batched import BatchedDriving

    specs = training_specs(cfg) if specs is None else specs
    check_devices(cfg)
    driving = BatchedDriving(specs, workers=cfg.workers, **env_options(cfg))
    driving.set_seed(training_seed(cfg))
    return driving


def make_env(cfg: TrainConfig, specs: list | None = None) -> TransformedEnv:
    """The same copies as a TorchRL env (``SmartsBatchedEnv`` with the episode statistics), what
    the Ray collectors step and TorchRL users train on."""
    from smarts.env.torchrl_env import SmartsBatchedEnv

    specs = training_specs(cfg) if specs is None else specs
    check_devices(cfg)
    env = TransformedEnv(SmartsBatchedEnv(specs, workers=cfg.workers, **env_options(cfg)), RewardSum())
    env.set_seed(training_seed(cfg))
    return env


def transformed_batched_env(specs: list, seed: int, options: dict) -> TransformedEnv:
    """One batch of scenario copies with the episode statistics training reads; module-level so
    that ``functools.partial`` of it pickles to Ray actors."""
    from smarts.env.torchrl_env import SmartsBatchedEnv

    env = TransformedEnv(SmartsBatchedEnv(specs, **options), RewardSum())
    env.set_seed(seed)
    return env


def ray_env_factories(cfg: TrainConfig) -> list:
    """Per Ray collector, a picklable factory of its share of the ``envs`` scenario copies. Each
    share keeps its copies' numbers in the whole batch (``copy_ids``), so with the one training
    seed every copy plays the episodes it plays without Ray."""
    if cfg.envs % cfg.workers or cfg.frames_per_batch % cfg.workers:
        raise ValueError(f"with ray_address, envs ({cfg.envs}) and frames_per_batch ({cfg.frames_per_batch}) "
                         f"must be multiples of workers ({cfg.workers})")  # fmt: skip
    specs = training_specs(cfg)
    shares = [list(range(w, cfg.envs, cfg.workers)) for w in range(cfg.workers)]
    # Ray stacks the collectors' batches: pad every collector to the same number of slots.
    slots = max(sum(not a.is_social for i in share for a in specs[i].agents) for share in shares)
    return [functools.partial(transformed_batched_env, [specs[i] for i in share], training_seed(cfg),
                              {**env_options(cfg), "slots": slots, "copy_ids": share})
            for share in shares]  # fmt: skip


# ------------------------------------------------------------------ the policy's parts
class _GaussianInActionUnits(nn.Module):
    """A Gaussian whose mean is the actor output mapped onto [low, high] (the same mean
    ``PPOPolicy`` acts with) and whose spread is relative to the action range. Samples may leave
    the box; the action limits of the simulator clip them (no tanh Jacobian, so PPO's ratios and
    entropy stay well behaved)."""

    def __init__(self, actor: Actor, low: torch.Tensor, high: torch.Tensor):
        super().__init__()
        self.actor = actor
        self.register_buffer("low", low.float())
        self.register_buffer("high", high.float())
        self.last: tuple[torch.Tensor, torch.Tensor] | None = None
        """(mean, scale) of the last pass with gradients (the loss's own actor pass), for the
        action-bound penalty and the KL estimate: they reuse that pass instead of running the
        actor again."""

    def forward(self, x: torch.Tensor):
        pre, std = self.actor(x)
        mean = scale_action(pre, self.low, self.high)
        scale = std * 0.5 * (self.high - self.low)
        if torch.is_grad_enabled():
            self.last = (mean, scale)
        return mean, scale

    def take_last(self) -> tuple[torch.Tensor, torch.Tensor]:
        last, self.last = self.last, None
        if last is None:
            raise RuntimeError("the PPO loss did not run the actor with gradients before the action-bound penalty")
        return last


class _FlatNormalised(nn.Module):
    """Concatenate the observation entries and normalise them, then apply ``head`` (the modules
    the Ray collectors act with: they read TorchRL's per-key observations)."""

    def __init__(self, layout: ObservationLayout, normalizer: ObsNormalizer, head: nn.Module):
        super().__init__()
        self.layout, self.normalizer, self.head = layout, normalizer, head

    def forward(self, *parts: torch.Tensor):
        flat = self.layout.flatten(dict(zip(self.layout.keys, parts)))
        return self.head(self.normalizer(flat))


def raw_features(layout: ObservationLayout, space: gym.spaces.Dict) -> torch.Tensor:
    """1 for the flat inputs the normaliser must pass unchanged: masks and 0/1 flags (entries
    bounded to [0, 1], and the flag columns of ``lead`` and ``signal``)."""
    from smarts.sensors.observation import LEAD_FEATURE_NAMES

    flags = {"lead": ("present", "visible", "in_lane"), "signal": (0, 1, 2), "ahead": (0,)}
    parts = []
    for key, shape in zip(layout.keys, layout.shapes):
        size = int(np.prod(shape))
        box = space.spaces[key]
        bounded01 = bool((box.low == 0).all()) and bool((box.high == 1).all())
        mark = torch.full((size,), 1.0 if bounded01 else 0.0)
        if key == "lead":
            mark[[LEAD_FEATURE_NAMES.index(n) for n in flags["lead"]]] = 1.0
        elif key in ("signal", "ahead"):
            mark[list(flags[key])] = 1.0
        parts.append(mark)
    return torch.cat(parts)


@dataclass
class PolicyParts:
    """The networks a run trains and checkpoints, and what they read and act in."""

    layout: ObservationLayout
    normalizer: ObsNormalizer
    actor_net: Actor
    critic_net: Critic
    head: _GaussianInActionUnits  # actor_net as a Gaussian in action units
    low: np.ndarray
    high: np.ndarray

    def to(self, device: torch.device) -> "PolicyParts":
        for module in (self.normalizer, self.actor_net, self.critic_net, self.head):
            module.to(device)
        return self


def build_parts(space: gym.spaces.Dict, low: np.ndarray, high: np.ndarray, cfg: TrainConfig) -> PolicyParts:
    """Networks for observations of ``space`` and actions in [``low``, ``high``] with the
    config's layers, initial spread and normaliser settings."""
    keys = tuple(sorted(space.spaces))
    layout = ObservationLayout(keys, tuple(tuple(space.spaces[k].shape) for k in keys))
    low, high = np.asarray(low, dtype=np.float32), np.asarray(high, dtype=np.float32)
    normalizer = ObsNormalizer(layout.size, clip=cfg.obs_clip, std_floor=cfg.obs_std_floor,
                               raw=raw_features(layout, space))  # fmt: skip
    size = len(low)
    actor_net = Actor(layout.size, size, tuple(cfg.hidden), init_log_std=initial_log_std(cfg.init_log_std, size))
    critic_net = Critic(layout.size, tuple(cfg.hidden))
    head = _GaussianInActionUnits(actor_net, torch.as_tensor(low), torch.as_tensor(high))
    return PolicyParts(layout, normalizer, actor_net, critic_net, head, low, high)


def driving_parts(driving, cfg: TrainConfig) -> PolicyParts:
    """``build_parts`` for a ``BatchedDriving`` (its observation space; slot 0's action box, the
    one the task's slots share)."""
    return build_parts(driving.observation_space, driving.action_low[0], driving.action_high[0], cfg)


def env_parts(env, cfg: TrainConfig) -> PolicyParts:
    """``build_parts`` for a TorchRL ``SmartsBatchedEnv`` (a Ray collector's share)."""
    return driving_parts(env.base_env.driving, cfg)


def collection_modules(parts: PolicyParts, action_spec) -> ProbabilisticActor:
    """The policy as TorchRL modules reading the per-key observations (what a Ray collector acts
    with), on the same networks and statistics."""
    in_keys = [("observation", k) for k in parts.layout.keys]
    policy = TensorDictModule(_FlatNormalised(parts.layout, parts.normalizer, parts.head), in_keys=in_keys,
                              out_keys=["loc", "scale"])  # fmt: skip
    return ProbabilisticActor(policy, in_keys=["loc", "scale"], spec=action_spec, distribution_class=IndependentNormal,
                              return_log_prob=True)  # fmt: skip


FLAT_OBSERVATION = "flat_observation"
"""Key of the normalised flat observation the PPO loss reads."""


def loss_modules(parts: PolicyParts) -> tuple[ProbabilisticActor, ValueOperator]:
    """The policy and critic as the update runs them, reading ``FLAT_OBSERVATION`` (normalised
    once per batch; the statistics stay fixed during an update)."""
    policy = TensorDictModule(parts.head, in_keys=[FLAT_OBSERVATION], out_keys=["loc", "scale"])
    actor = ProbabilisticActor(policy, in_keys=["loc", "scale"], distribution_class=IndependentNormal,
                               return_log_prob=True)  # fmt: skip
    return actor, ValueOperator(parts.critic_net, in_keys=[FLAT_OBSERVATION])


# ------------------------------------------------------------------ collection
class Inference(nn.Module):
    """The acting copy of the policy: normalise the flat observations, run the actor, sample a
    Gaussian action with its own generator and return it with its log-probability, in one pass.
    A copy (``sync`` loads the learner's weights and statistics) so that collection can run while
    the learner updates its own."""

    def __init__(self, parts: PolicyParts, device: torch.device, seed: int):
        super().__init__()
        self.normalizer = ObsNormalizer(parts.layout.size)
        self.actor = Actor(parts.layout.size, len(parts.low), tuple(parts.actor_net.hidden))
        self.register_buffer("low", torch.as_tensor(parts.low))
        self.register_buffer("high", torch.as_tensor(parts.high))
        self.to(device)
        self.device = device
        self.generator = torch.Generator(device=device).manual_seed(seed)

    @torch.no_grad()
    def sync(self, parts: PolicyParts) -> None:
        self.actor.load_state_dict(parts.actor_net.state_dict())
        self.normalizer.load_state_dict(parts.normalizer.state_dict())

    @torch.no_grad()
    def forward(self, obs: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        pre, std = self.actor(self.normalizer(obs))
        mean = scale_action(pre, self.low, self.high)
        scale = std * 0.5 * (self.high - self.low)
        action = mean + scale * torch.randn(mean.shape, generator=self.generator, device=self.device)
        return action, torch.distributions.Normal(mean, scale).log_prob(action).sum(-1)


@dataclass
class Batch:
    """A batch of slot-steps, time first ([T, S, ...]), on the learner's device."""

    obs: torch.Tensor  # [T, S, D] raw flat observations the policy acted on (zeros while waiting)
    action: torch.Tensor  # [T, S, A]
    log_prob: torch.Tensor  # [T, S] of the action under the policy that acted
    reward: torch.Tensor  # [T, S]
    done: torch.Tensor  # [T, S] the slot's episode ended with this step
    terminated: torch.Tensor  # [T, S] ... by a terminal event (no bootstrap)
    valid: torch.Tensor  # [T, S] the slot's agent acted (a real transition)
    own_next: torch.Tensor  # [T, S] the next observation is not obs[t + 1] (an episode's end, the last step)
    own_next_obs: torch.Tensor  # [K, D] those next observations, in the row order of own_next
    episode_returns: np.ndarray  # of the episodes that ended in the batch, in the reward's units
    episode_lengths: np.ndarray

    @property
    def frames(self) -> int:
        return int(self.valid.numel())


class _Part:
    """Slots a ``BatchedDriving`` steps together (one of its ``parts``), with the collector's
    buffers for them."""

    def __init__(self, index: int, rows, n: int, d: int, device: torch.device):
        self.index = index
        self.ids = np.arange(n)[rows]  # the part's slots
        whole = isinstance(rows, slice)
        self.rows = rows if whole else torch.from_numpy(self.ids)  # indexes torch tensors
        self.device_rows = rows if whole else self.rows.to(device)
        self.flat = torch.zeros(len(self.ids), d)  # its slots' observations after a step
        self.first = torch.zeros(len(self.ids), d)  # ... and first observations of restarted copies


class SlotCollector:
    """Steps a ``BatchedDriving`` for batches of slot-steps with an ``Inference`` policy, reading
    and writing the env's flat buffers (in shared memory when the copies run in workers).

    A slot whose agent has finished *waits* (zero observation, not valid) until every agent of its
    copy has finished; the copy then restarts and the slot goes on from the new episode's first
    observation. Where the env steps its slots in two parts (copies in two or more worker
    processes), the policy acts for one part while the other part's workers step, so inference
    and simulation overlap instead of taking turns; each slot sees the same sequence of steps.
    ``stop`` ends a collection at the next step (Ctrl-C while overlapping)."""

    def __init__(self, driving, layout: ObservationLayout, policy: Inference, device: torch.device):
        self.driving, self.layout, self.policy, self.device = driving, layout, policy, device
        n, d = driving.num_slots, layout.size
        self.width = driving.action_width
        self.parts = [_Part(i, rows, n, d, device) for i, rows in enumerate(driving.parts)]
        self.obs = torch.zeros(n, d)  # the observation each slot acts on next
        self.live = np.zeros(n, dtype=bool)
        self.returns = np.zeros(n)
        self.lengths = np.zeros(n, dtype=np.int64)
        self.stop = threading.Event()
        self.started = False

    def flatten(self, obs: dict[str, np.ndarray], out: torch.Tensor) -> torch.Tensor:
        """The per-key arrays of some slots as one [slots, D] float32 tensor (one copy)."""
        n = out.shape[0]
        torch.cat([torch.from_numpy(obs[k]).reshape(n, -1) for k in self.layout.keys], dim=1, out=out)
        return out

    def reset(self) -> None:
        self.flatten(self.driving.reset(), self.obs)
        self.live[:] = True
        self.returns[:] = 0.0
        self.lengths[:] = 0
        self.started = True

    def collect(self, steps: int) -> Batch:
        if not self.started:
            self.reset()
        n, d, dev = self.driving.num_slots, self.layout.size, self.device
        batch = _Steps(
            obs=torch.empty(steps, n, d, device=dev), action=torch.empty(steps, n, self.width, device=dev),
            log_prob=torch.empty(steps, n, device=dev), reward=np.zeros((steps, n), dtype=np.float32),
            done=np.zeros((steps, n), dtype=bool), terminated=np.zeros((steps, n), dtype=bool),
            valid=np.zeros((steps, n), dtype=bool),
        )  # fmt: skip
        for part in self.parts:
            self.driving.begin_step(self.act(batch, 0, part), part.index)
        for t in range(steps):
            for part in self.parts:  # while one part steps, the policy acts for the other
                if self.stop.is_set():
                    raise KeyboardInterrupt
                self.record(batch, t, part, self.driving.end_step(part.index), last=t == steps - 1)
                if t + 1 < steps:
                    self.driving.begin_step(self.act(batch, t + 1, part), part.index)
        return batch.done_batch(n, d, dev)

    def act(self, batch: _Steps, t: int, part: _Part) -> np.ndarray:
        """The policy's actions for ``part``'s slots at step ``t`` (recorded with what it acted on)."""
        rows = part.device_rows
        batch.obs[t][rows] = self.obs[part.rows].to(self.device, non_blocking=True)
        batch.valid[t, part.ids] = self.live[part.ids]
        action, log_prob = self.policy(batch.obs[t][rows])
        batch.action[t][rows], batch.log_prob[t][rows] = action, log_prob
        return action.cpu().numpy()[:, : self.width]

    def record(self, batch: _Steps, t: int, part: _Part, res, last: bool) -> None:
        """Step ``t``'s results for ``part``'s slots, and what each of them acts on next."""
        ids, n = part.ids, self.driving.num_slots
        ended = res.terminated | res.truncated
        batch.reward[t, ids], batch.done[t, ids], batch.terminated[t, ids] = res.reward, ended, res.terminated
        following = self.flatten(res.obs, part.flat)
        acted = ids[res.acted]
        self.returns[acted] += res.reward[res.acted]
        self.lengths[acted] += 1
        if ended.any():
            local = np.flatnonzero(ended)
            rows = ids[local]
            batch.returns.append(self.returns[rows].copy())
            batch.lengths.append(self.lengths[rows].copy())
            self.returns[rows], self.lengths[rows] = 0.0, 0
            if not last:  # the last step's next observations are taken below, for every slot
                batch.own_rows.append(t * n + rows)
                batch.own_obs.append(following[local].clone())
        # What each slot acts on next: the following observation, zeros once its agent has
        # finished, the new episode's first observation where its copy restarted.
        nxt = following.clone() if last else following
        nxt[torch.from_numpy(ended)] = 0.0
        self.live[ids] &= ~ended
        if res.restarted.any():
            again = torch.from_numpy(res.restarted)
            nxt[again] = self.flatten(res.first, part.first)[again]
            self.live[ids] |= res.restarted
        if last:  # the next observation of every slot: its final one where it ended, else the carried one
            tail = torch.where(torch.from_numpy(ended)[:, None], following, nxt)
            batch.own_rows.append(t * n + ids)
            batch.own_obs.append(tail)
        self.obs[part.rows] = nxt


@dataclass
class _Steps:
    """A batch being collected: the per-step arrays [T, S, ...] and the rows whose next
    observation is their own (``Batch.own_next``), with those observations."""

    obs: torch.Tensor
    action: torch.Tensor
    log_prob: torch.Tensor
    reward: np.ndarray
    done: np.ndarray
    terminated: np.ndarray
    valid: np.ndarray
    own_rows: list = field(default_factory=list)
    own_obs: list = field(default_factory=list)
    returns: list = field(default_factory=list)
    lengths: list = field(default_factory=list)

    def done_batch(self, n: int, d: int, dev: torch.device) -> Batch:
        steps = self.obs.shape[0]
        own_next = torch.zeros(steps * n, dtype=torch.bool)
        rows = np.concatenate(self.own_rows) if self.own_rows else np.zeros(0, dtype=np.int64)
        own_next[torch.from_numpy(rows)] = True
        order = np.argsort(rows, kind="stable")  # own_next_obs in the row order of own_next
        own_stack = torch.cat(self.own_obs)[torch.from_numpy(order)] if self.own_obs else torch.zeros(0, d)
        return Batch(
            obs=self.obs, action=self.action, log_prob=self.log_prob,
            reward=torch.from_numpy(self.reward).to(dev), done=torch.from_numpy(self.done).to(dev),
            terminated=torch.from_numpy(self.terminated).to(dev), valid=torch.from_numpy(self.valid).to(dev),
            own_next=own_next.reshape(steps, n).to(dev), own_next_obs=own_stack.to(dev),
            episode_returns=np.concatenate(self.returns) if self.returns else np.zeros(0),
            episode_lengths=np.concatenate(self.lengths) if self.lengths else np.zeros(0),
        )  # fmt: skip


def batch_from_tensordict(data, layout: ObservationLayout, device: torch.device) -> Batch:
    """A [slots, time] TensorDict of TorchRL's collector (the Ray path) as a ``Batch``."""
    data = data.reshape(-1, data.shape[-1]).to(device)
    obs = layout.flatten({k: data["observation", k] for k in layout.keys}).transpose(0, 1).contiguous()
    following = layout.flatten({k: data["next", "observation", k] for k in layout.keys}).transpose(0, 1)
    own = torch.ones(obs.shape[:2], dtype=torch.bool, device=device)
    own[:-1] = (following[:-1] != obs[1:]).any(-1)
    done = data["next", "done"][..., 0].transpose(0, 1)
    valid = data["valid"][..., 0].transpose(0, 1)
    ended = (done & valid).cpu().numpy()
    return Batch(
        obs=obs, action=data["action"].transpose(0, 1), log_prob=data["action_log_prob"].transpose(0, 1),
        reward=data["next", "reward"][..., 0].transpose(0, 1), done=done,
        terminated=data["next", "terminated"][..., 0].transpose(0, 1), valid=valid,
        own_next=own, own_next_obs=following[own],
        episode_returns=data["next", "episode_reward"][..., 0].transpose(0, 1).cpu().numpy()[ended],
        episode_lengths=data["next", "agent_steps"][..., 0].transpose(0, 1).cpu().numpy()[ended],
    )  # fmt: skip


# ------------------------------------------------------------------ learning
class RewardScaler:
    """Divides rewards by a running standard deviation of the discounted return (per slot), so the
    critic regresses targets of order one whatever the reward's scale (the usual PPO reward
    normalisation; the logged episode returns stay in the reward's own units)."""

    def __init__(self, gamma: float):
        self.gamma = gamma
        self.returns: torch.Tensor | None = None
        self.mean, self.var, self.count = 0.0, 1.0, 1e-4

    def __call__(self, batch: Batch) -> None:
        reward, done, valid = batch.reward, batch.done.float(), batch.valid.float()  # [T, S]
        if self.returns is None or self.returns.shape[0] != reward.shape[1]:
            self.returns = torch.zeros(reward.shape[1], device=reward.device)
        seen = []
        for t in range(reward.shape[0]):
            self.returns = self.returns * self.gamma * valid[t] + reward[t] * valid[t]
            seen.append(self.returns[valid[t] > 0])
            self.returns = self.returns * (1.0 - done[t])
        values = torch.cat(seen) if seen else torch.zeros(0)
        if values.numel() > 1:
            b_mean, b_var, n = float(values.mean()), float(values.var(unbiased=False)), values.numel()
            delta, total = b_mean - self.mean, self.count + n
            self.mean += delta * n / total
            self.var = (self.var * self.count + b_var * n + delta**2 * self.count * n / total) / total
            self.count = total
        batch.reward = reward / max(self.var**0.5, 1e-4)


def action_bound_loss(mean: torch.Tensor, low: torch.Tensor, high: torch.Tensor) -> torch.Tensor:
    """Squared distance of the Gaussian's mean outside the action box. Beyond the box the simulator
    clips every sample to the same action, so PPO's gradient there is noise and the mean drifts
    away (and a lane change requested at +3 means the same as at +0.6); this keeps it in reach."""
    return ((mean - high).clamp(min=0.0) ** 2 + (low - mean).clamp(min=0.0) ** 2).sum(-1).mean()


def kl_estimate(mean, scale, action, old_log_prob) -> torch.Tensor:
    """``E[(r - 1) - log r]`` with ``r`` the probability ratio of the taken actions: an estimate
    of KL(old || new) that is never negative (each term is), unlike the mean of ``-log r``."""
    new = torch.distributions.Normal(mean, scale).log_prob(action).sum(-1)
    log_ratio = new - old_log_prob
    return (log_ratio.exp() - 1.0 - log_ratio).mean()


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


UPDATE_STATS = ("objective", "critic", "entropy_loss", "entropy", "kl", "clip", "explained", "grad")
"""What ``Learner.update`` records per minibatch step (its metrics are their means)."""


class Learner:
    """PPO updates of ``parts`` on ``device``: torchrl's GAE (``vec_generalized_advantage_estimate``)
    per slot trajectory, its ``ClipPPOLoss`` over random minibatches of the valid steps, Adam with
    gradient clipping, the KL stop, the action-bound penalty and the observation statistics."""

    def __init__(self, cfg: TrainConfig, parts: PolicyParts, device: torch.device):
        self.cfg, self.parts, self.device = cfg, parts, device
        actor, critic = loss_modules(parts)
        self.loss = ClipPPOLoss(actor, critic, clip_epsilon=cfg.clip_epsilon, entropy_coeff=cfg.entropy_coeff,
                                critic_coeff=cfg.critic_coeff, loss_critic_type="l2", normalize_advantage=True)  # fmt: skip
        self.loss.set_keys(sample_log_prob="action_log_prob")
        self.optimizer = torch.optim.Adam(self.loss.parameters(), lr=cfg.lr)
        self.scale_rewards = RewardScaler(cfg.gamma) if cfg.reward_scaling else None
        self.low, self.high = torch.as_tensor(parts.low, device=device), torch.as_tensor(parts.high, device=device)

    def minibatches(self, rows: torch.Tensor, columns: dict[str, torch.Tensor]):
        """Every one of ``rows`` once, in random minibatches of ``minibatch_size`` (the last one
        smaller), each gathered straight from the batch's flat ``columns``. (torchrl's
        ``ReplayBuffer`` with its ``SamplerWithoutReplacement`` first copies the epoch's steps into
        its storage: 27 against 11 ms per epoch of 16,000 steps here, a tenth of an update, so the
        update draws its own permutation.)"""
        order = rows[torch.randperm(len(rows), device=rows.device)]
        for start in range(0, len(order), self.cfg.minibatch_size):
            pick = order[start : start + self.cfg.minibatch_size]
            yield TensorDict({k: v[pick] for k, v in columns.items()}, batch_size=[len(pick)], device=self.device)

    @torch.no_grad()
    def _values(self, x: torch.Tensor, own_x: torch.Tensor, own: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """State values [T, S] of every step and of its next observation: the following step's
        value, except where the next observation is the slot's own (``own``): one critic pass over
        the batch instead of two."""
        critic = self.parts.critic_net
        value = critic(x).squeeze(-1)
        next_value = torch.empty_like(value)
        next_value[:-1] = value[1:]
        if own_x.shape[0]:
            next_value[own] = critic(own_x).squeeze(-1)
        return value, next_value

    def update(self, batch: Batch) -> dict[str, float]:
        """One PPO update on ``batch``: ``epochs`` passes of GAE and clipped-loss minibatch steps
        (until the KL stop), then the observation statistics; the batch's training metrics."""
        if self.scale_rewards is not None:
            self.scale_rewards(batch)
        x, own_x, rows = self.normalised(batch)
        stats: dict[str, list[float]] = {k: [] for k in UPDATE_STATS}
        for _ in range(self.cfg.epochs):
            columns = self.advantages(batch, x, own_x)
            if not self.epoch(rows, columns, stats):
                break  # the policy has moved far enough on this batch (as SB3 does)
        clipped = self.refresh_statistics(batch, x, rows)
        return self.summary(stats, clipped, len(rows), batch.frames)

    @torch.no_grad()
    def normalised(self, batch: Batch) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """The batch's observations [T, S, D] and own next observations [K, D] normalised once for
        the whole update (the statistics change only after it), and the flat rows of valid steps."""
        steps, slots, size = batch.obs.shape
        x = self.parts.normalizer(batch.obs.reshape(-1, size)).reshape(steps, slots, size)
        own_x = self.parts.normalizer(batch.own_next_obs)
        rows = torch.nonzero(batch.valid.reshape(-1)).squeeze(-1)
        return x, own_x, rows

    def advantages(self, batch: Batch, x: torch.Tensor, own_x: torch.Tensor) -> dict[str, torch.Tensor]:
        """GAE on each slot's trajectory [S, T, 1] with the critic as updated so far (once per
        batch learned markedly slower): the flat columns the loss reads, one row per slot-step."""
        cfg = self.cfg
        steps, slots, size = x.shape
        value, next_value = self._values(x, own_x, batch.own_next)
        advantage, target = vec_generalized_advantage_estimate(
            cfg.gamma, cfg.gae_lambda, value.T[..., None], next_value.T[..., None], batch.reward.T[..., None],
            batch.done.T[..., None], batch.terminated.T[..., None], time_dim=-2,
        )  # fmt: skip
        return {
            FLAT_OBSERVATION: x.reshape(-1, size),
            "action": batch.action.reshape(steps * slots, -1),
            "action_log_prob": batch.log_prob.reshape(-1),
            "advantage": advantage.transpose(0, 1).reshape(-1, 1),
            "value_target": target.transpose(0, 1).reshape(-1, 1),
        }

    def epoch(self, rows: torch.Tensor, columns: dict[str, torch.Tensor], stats: dict[str, list[float]]) -> bool:
        """One pass over the valid ``rows`` in random minibatches; False when the KL stop ended it
        (the steps of waiting slots are not among ``rows``)."""
        return all(self.gradient_step(minibatch, stats) for minibatch in self.minibatches(rows, columns))

    def gradient_step(self, minibatch: TensorDict, stats: dict[str, list[float]]) -> bool:
        """``ClipPPOLoss`` (with the action-bound penalty), Adam and gradient clipping on one
        minibatch, its losses appended to ``stats``; False, and no step, past ``target_kl``."""
        cfg, parts = self.cfg, self.parts
        losses = self.loss(minibatch)
        mean, scale = parts.head.take_last()  # the actor's pass inside the loss
        kl = float(kl_estimate(mean.detach(), scale.detach(), minibatch["action"], minibatch["action_log_prob"]))
        if cfg.target_kl and kl > cfg.target_kl:
            return False
        total = losses["loss_objective"] + losses["loss_critic"] + losses["loss_entropy"]
        if cfg.action_bound_coeff > 0:
            total = total + cfg.action_bound_coeff * action_bound_loss(mean, self.low, self.high)
        self.optimizer.zero_grad()
        total.backward()
        grad = nn.utils.clip_grad_norm_(self.loss.parameters(), cfg.max_grad_norm)
        self.optimizer.step()
        for key, value in (("objective", losses["loss_objective"]), ("critic", losses["loss_critic"]),
                           ("entropy_loss", losses["loss_entropy"]), ("entropy", losses.get("entropy")),
                           ("clip", losses.get("clip_fraction")), ("explained", losses.get("explained_variance")),
                           ("grad", grad)):  # fmt: skip
            stats[key].append(float(value.detach()) if value is not None else float("nan"))
        stats["kl"].append(kl)
        return True

    def refresh_statistics(self, batch: Batch, x: torch.Tensor, rows: torch.Tensor) -> float:
        """The observation normaliser takes the batch's valid steps (only now: during the update the
        policy must see its inputs exactly as it did when it acted, or PPO's probability ratios are
        off); the fraction of inputs its clip cut."""
        size = batch.obs.shape[-1]
        inputs = batch.obs.reshape(-1, size)
        # The health check on every 8th valid step: an estimate at an eighth of the cost of all.
        clipped = self.parts.normalizer.clipped_fraction(inputs, normalised=x.reshape(-1, size), rows=rows[::8])
        if self.cfg.obs_norm:
            self.parts.normalizer.update(inputs[rows])
        return clipped

    def summary(self, stats: dict[str, list[float]], clipped: float, valid: int, frames: int) -> dict[str, float]:
        """The update's TensorBoard scalars: means over its minibatch steps and the state after it."""

        def mean_of(key: str) -> float:
            return float(np.mean(stats[key])) if stats[key] else float("nan")

        return {
            "loss/objective": mean_of("objective"),
            "loss/critic": mean_of("critic"),
            "loss/entropy": mean_of("entropy_loss"),
            "policy/entropy": mean_of("entropy"),
            "policy/kl_approx": mean_of("kl"),
            "policy/clip_fraction": mean_of("clip"),
            "policy/action_std": float(self.parts.actor_net.log_std.detach().clamp(-3.0, 0.5).exp().mean()),
            "train/explained_variance": mean_of("explained"),
            "train/grad_norm": mean_of("grad"),
            "obs/clipped_fraction": clipped,
            "train/lr": self.optimizer.param_groups[0]["lr"],
            "train/valid_fraction": float(valid / max(frames, 1)),
        }


# ------------------------------------------------------------------ where batches come from
class Collection:
    """Where batches come from: ``start`` begins a batch of ``steps`` per slot, ``take`` waits for
    it, ``sync`` gives the acting policy the learner's weights (never while collecting)."""

    overlap = False

    def start(self, steps: int) -> None:
        raise NotImplementedError

    def take(self) -> Batch:
        raise NotImplementedError

    def sync(self, parts: PolicyParts) -> None:
        raise NotImplementedError

    def close(self) -> None:
        raise NotImplementedError

    def start_next(self, parts: PolicyParts, steps: int | None) -> None:
        """The acting copy takes the learner's weights, then begins the next batch (none after the last)."""
        if steps is not None:
            self.sync(parts)
            self.start(steps)


class LocalCollection(Collection):
    """Batches from the ``BatchedDriving`` of this run (copies in this process or in shared-memory
    workers); with ``overlap`` the next batch is collected in a thread while the learner updates
    (the torch ops and the workers' stepping release the interpreter lock)."""

    def __init__(self, cfg: TrainConfig, driving, parts: PolicyParts, device: torch.device):
        self.driving = driving
        self.policy = Inference(parts, device, seed=cfg.seed * 7919 + 17)
        self.policy.sync(parts)
        self.collector = SlotCollector(driving, parts.layout, self.policy, device)
        self.overlap = cfg.overlap
        self.pool = ThreadPoolExecutor(max_workers=1, thread_name_prefix="collect") if cfg.overlap else None
        self.pending = None

    @property
    def slots(self) -> int:
        return self.driving.num_slots

    def start(self, steps: int) -> None:
        """Begin collecting a batch of ``steps`` per slot (in the background with ``overlap``)."""
        if self.pool is not None:
            self.pending = self.pool.submit(self.collector.collect, steps)
        else:
            self.pending = steps

    def take(self) -> Batch:
        """The batch ``start`` began (waiting for it)."""
        pending, self.pending = self.pending, None
        return pending.result() if self.pool is not None else self.collector.collect(pending)

    def sync(self, parts: PolicyParts) -> None:
        """The acting copy takes the learner's weights and statistics (never while collecting)."""
        self.policy.sync(parts)

    def close(self) -> None:
        self.collector.stop.set()
        if self.pool is not None:
            if self.pending is not None:
                with contextlib.suppress(BaseException):
                    self.pending.result()
                self.pending = None
            self.pool.shutdown(wait=True)
        self.driving.close()


class RayCollection(Collection):
    """Batches from torchrl's ``Collector`` with ``backend="ray"``: each of the ``workers`` Ray
    actors steps its share of the copies as a ``SmartsBatchedEnv``, acting with the policy's
    TorchRL modules; the learner sends the new weights after every update (no overlap).

    The weights travel through Ray's object store, which the session keeps on loopback. torchrl's
    default for Ray collectors (``RayWeightSyncScheme``) opens a ``TCPStore`` and Gloo sockets on
    every interface instead, so it is switched off (``weight_sync_schemes={}``) and :meth:`sync`
    hands each actor the weights itself."""

    overlap = False

    def __init__(self, cfg: TrainConfig, factories: list, parts: PolicyParts, action_spec, slots: int, plan: BatchPlan,
                 device: torch.device):  # fmt: skip
        from torchrl.collectors import Collector

        self.layout, self.device = parts.layout, device
        self.actor = collection_modules(parts, action_spec)
        self._slots = slots
        self.collector = Collector(factories, self.actor, backend="ray", num_collectors=cfg.workers, sync=True,
                                   frames_per_batch=plan.first_steps * slots, total_frames=plan.frames,
                                   remote_configs={"num_cpus": 1}, weight_sync_schemes={})  # fmt: skip
        self.sync(parts)  # the actors start from these (possibly resumed) weights
        self.iterator = iter(self.collector)

    @property
    def slots(self) -> int:
        return self._slots

    def start(self, steps: int) -> None:
        pass

    def take(self) -> Batch:
        with warnings.catch_warnings():  # torchrl warns that its own weight sync never ran: ours did
            warnings.filterwarnings("ignore", "RayCollector iteration started before weight synchronization")
            return batch_from_tensordict(next(self.iterator), self.layout, self.device)

    def sync(self, parts: PolicyParts) -> None:
        import ray

        weights = ray.put(TensorDict.from_module(self.actor).data)
        ray.get([actor.update_policy_weights_.remote(weights) for actor in self.collector.remote_collectors])

    def close(self) -> None:
        if self.collector is not None:
            self.collector.shutdown()
            self.collector = None


# ------------------------------------------------------------------ the run's setup
@dataclass
class Start:
    """What a run's networks start from: the checkpoint it continues (``resume``: networks,
    observation statistics, optimiser, step count), trained networks a new run fine-tunes
    (``init_from``: networks and statistics, a fresh optimiser), or nothing."""

    blob: dict | None = None
    source: Path | str | None = None
    resumed: bool = False

    @classmethod
    def check(cls, cfg: TrainConfig, resume: Path | None) -> Start:
        """Read and check the checkpoint, before anything is built or written."""
        blob = check_resume(resume, cfg) if resume is not None else None
        start_from = check_init_from(Path(cfg.init_from), cfg) if cfg.init_from else None
        if blob is not None and start_from is not None:
            raise ValueError("resume continues a run and init_from starts a new one from trained networks: give one")
        if blob is not None:
            return cls(blob, resume, resumed=True)
        return cls(start_from, cfg.init_from) if start_from is not None else cls()

    def restore(self, parts: PolicyParts, learner: Learner) -> int:
        """Load the checkpoint into ``parts`` (and the optimiser when resuming); the step to go on from."""
        if self.blob is None:
            return 0
        try:
            parts.actor_net.load_state_dict(self.blob["actor"])
            parts.critic_net.load_state_dict(self.blob["critic"])
            parts.normalizer.load_state_dict(self.blob["normalizer"])
            if self.resumed and "optimizer" in self.blob:
                learner.optimizer.load_state_dict(self.blob["optimizer"])
        except (RuntimeError, ValueError) as err:
            raise CheckpointError(f"{self.source}: does not match this training setup ({err})") from None
        return int(self.blob["step"]) if self.resumed else 0


@dataclass
class TrainingEnvs:
    """The run's scenario copies before collection begins, with the networks built for them: a
    ``BatchedDriving`` here (``driving``) or, with ``ray_address``, the Ray collectors' env
    factories and the action spec of their TorchRL envs."""

    parts: PolicyParts
    slots: int
    driving: object = None
    factories: list | None = None
    action_spec: object = None

    def collection(self, cfg: TrainConfig, plan: BatchPlan, device: torch.device) -> Collection:
        """Where the batches come from, acting with the (possibly restored) networks."""
        if self.factories is not None:
            return RayCollection(cfg, self.factories, self.parts, self.action_spec, self.slots, plan, device)
        return LocalCollection(cfg, self.driving, self.parts, device)


def open_envs(cfg: TrainConfig, specs: list | None, scale_out: contextlib.ExitStack) -> TrainingEnvs:
    """The ``envs`` copies and their networks: one ``BatchedDriving`` (over ``workers`` processes),
    or with ``ray_address`` a Ray session held by ``scale_out`` and one env per Ray collector."""
    if cfg.ray_address:
        return open_ray_envs(cfg, scale_out)
    driving = make_driving(cfg, specs)
    return TrainingEnvs(driving_parts(driving, cfg), driving.num_slots, driving=driving)


def open_ray_envs(cfg: TrainConfig, scale_out: contextlib.ExitStack) -> TrainingEnvs:
    """The Ray collectors' env factories; one share is built here only for the specs the networks
    are built from, then the Ray session starts."""
    from smarts.ray_session import ray_session

    factories = ray_env_factories(cfg)
    env = factories[0]()
    parts, action_spec = env_parts(env, cfg), env.action_spec
    slots = int(np.prod(env.batch_size)) * cfg.workers
    env.close()
    scale_out.enter_context(ray_session(cfg.ray_address, num_cpus=max(2, cfg.workers)))
    return TrainingEnvs(parts, slots, factories=factories, action_spec=action_spec)


def save_run_checkpoint(path: Path, cfg: TrainConfig, parts: PolicyParts, learner: Learner, step: int,
                        metrics: dict) -> Path:  # fmt: skip
    """A checkpoint of the run at ``step``: networks, statistics, action and observation contract,
    config, the latest metrics and the optimiser (for ``resume``)."""
    return save_checkpoint(path, actor=parts.actor_net, critic=parts.critic_net, normalizer=parts.normalizer,
                           layout=parts.layout, low=parts.low, high=parts.high,
                           action_space=ACTION_SPACES[cfg.action_space], controller=cfg.controller,
                           interface=interface_dict(cfg), lane_relative=lane_relative_dict(cfg),
                           comms=comms_dict(cfg), config=cfg.model_dump(), step=step, metrics=metrics,
                           optimizer_state=learner.optimizer.state_dict())  # fmt: skip


def timed(fn, *args):
    """``fn(*args)`` and the seconds it took."""
    began = time.perf_counter()
    result = fn(*args)
    return result, time.perf_counter() - began


def batch_metrics(batch: Batch, wait_s: float, update_s: float, steps_per_s: float) -> dict[str, float]:
    """The batch's timings and the returns and lengths of the episodes that ended in it."""
    metrics = {
        "perf/update_s": update_s,
        "perf/wait_s": wait_s,  # > 0 when collection, not the update, sets the pace
        "perf/env_steps_per_s": steps_per_s,
    }
    if len(batch.episode_returns):
        metrics["episode/return"] = float(batch.episode_returns.mean())
        metrics["episode/length"] = float(batch.episode_lengths.mean())
    return metrics


# ------------------------------------------------------------------ the run
def train(cfg: TrainConfig, out: Path, progress: bool = True, resume: Path | None = None) -> Path:
    """Train, log and checkpoint under ``out``; returns the final checkpoint path. ``resume``
    continues from a checkpoint (networks, observation statistics, optimiser, step count) up to
    ``total_steps``."""
    torch.set_num_threads(cfg.torch_threads)
    start = Start.check(cfg, resume)  # resume or init_from, refused before anything is built
    check_devices(cfg)
    device = learner_device(cfg)
    specs = None if cfg.ray_address else training_specs(cfg)
    torch.manual_seed(cfg.seed)
    np.random.seed(cfg.seed)
    run = Run(cfg, out, resume, progress=progress)  # the run folder (never another run's), config.json, TensorBoard
    scale_out = contextlib.ExitStack()  # the Ray session, with ray_address

    # Setup: the env copies, the actor-critic, the PPO loss and its optimiser, the collector.
    envs = open_envs(cfg, specs, scale_out)
    parts = envs.parts.to(device)
    learner = Learner(cfg, parts, device)
    step = start.restore(parts, learner)
    # Ray's collector takes whole batches; the local one ends the run within one step of every slot.
    plan = BatchPlan.of(cfg.total_steps - step, cfg.frames_per_batch, envs.slots, whole=bool(cfg.ray_address))
    source = envs.collection(cfg, plan, device)
    metrics: dict[str, float] = {}

    def save(path: Path) -> Path:
        return save_run_checkpoint(path, cfg, parts, learner, step, metrics)

    bar = Progress(f"PPO {cfg.task}", cfg.total_steps, step, enabled=progress)
    began, first_step = time.perf_counter(), step
    try:
        batches = list(plan.steps_per_batch())
        source.start_next(parts, batches[0])
        for following in [*batches[1:], None]:
            batch, wait_s = timed(source.take)  # collection
            if source.overlap:  # the next batch is collected while this one trains (one update behind)
                source.start_next(parts, following)
            metrics, update_s = timed(learner.update, batch)  # GAE, then epochs of minibatch steps
            step += batch.frames
            metrics.update(batch_metrics(batch, wait_s, update_s, (step - first_step) / (time.perf_counter() - began)))
            if not source.overlap:
                source.start_next(parts, following)
            run.end_of_batch(step, batch.frames, metrics, save)  # TensorBoard, last.pt, every eval_every: best.pt
            bar.update(step, metrics)
    except KeyboardInterrupt:
        bar.close()
        source.close()
        run.interrupted(step, save)  # interrupted.pt
        raise
    finally:
        bar.close()
        source.close()
        scale_out.close()
    return run.finish(step, metrics, save, began)  # final.pt, its evaluation, the summary
