"""TorchRL environments: one scenario (``SmartsTorchRLEnv``, over ``DrivingParallelEnv``) and
scenario copies as slots (``SmartsBatchedEnv``, over the batched core ``BatchedDriving``).

Multi-agent scenarios put every per-agent entry under one agent group (``"agents"`` by default)
with a leading agent dimension of ``len(possible_agents)``: agents finish at different times, so a
fixed-size group plus a live ``mask`` keeps the tensor shapes constant over an episode. A scenario
with one learning agent (or ``single_agent=True``) uses the flat keys of a single-agent env.

``SmartsBatchedEnv`` is the batched env to train with: every learning agent of every copy is a
slot, and copies with SUMO traffic run in worker processes of their own behind it. TorchRL's own
batching of ``SmartsTorchRLEnv`` stays available: libsumo runs one SUMO per process, so
``make_parallel_env`` puts each copy in a worker process; ``make_serial_env`` steps copies in this
process (no SUMO traffic, or one env).
"""

from __future__ import annotations

import functools
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np
import torch
from tensordict import TensorDict, TensorDictBase
from torchrl.data import Bounded, Categorical, Composite, TensorSpec, Unbounded
from torchrl.envs import EnvBase, ParallelEnv, SerialEnv

from smarts.core.simulation import check_seed, derived_seed
from smarts.core.spec import replace
from smarts.env.assembly import as_spec
from smarts.env.batched.driving import BatchedDriving
from smarts.env.parallel_env import DrivingParallelEnv
from smarts.env.slots import check_slot_actions, not_started
from smarts.scenario import ScenarioSpec

ScenarioSource = str | Path | ScenarioSpec | DrivingParallelEnv


def space_to_spec(space: gym.Space, lead: tuple[int, ...] = (), device: torch.device | str = "cpu") -> TensorSpec:
    """The TorchRL spec of one gymnasium space, with ``lead`` dimensions in front (the agent dim).

    A Box with finite bounds becomes ``Bounded`` (so random actions and ``check_env_specs`` respect
    them); one with any infinite bound ``Unbounded``; a Discrete ``Categorical``."""
    if isinstance(space, gym.spaces.Box):
        dtype = torch.from_numpy(np.zeros(0, dtype=space.dtype)).dtype
        shape = (*lead, *space.shape)
        if np.isfinite(space.low).all() and np.isfinite(space.high).all():
            low = torch.from_numpy(np.broadcast_to(space.low, shape).copy())
            high = torch.from_numpy(np.broadcast_to(space.high, shape).copy())
            return Bounded(low=low, high=high, shape=shape, dtype=dtype, device=device)
        return Unbounded(shape=shape, dtype=dtype, device=device)
    if isinstance(space, gym.spaces.Discrete) and int(space.start) == 0:
        return Categorical(int(space.n), shape=lead, dtype=torch.int64, device=device)
    raise TypeError(
        f"no TorchRL spec for a {type(space).__name__} space ({space}); expected a Box or a Discrete from 0"
    )


def _flag_spec(shape: tuple[int, ...], device) -> Categorical:
    return Categorical(2, shape=shape, dtype=torch.bool, device=device)


def _done_specs(shape: tuple[int, ...], device) -> dict[str, Categorical]:
    return {k: _flag_spec(shape, device) for k in ("done", "terminated", "truncated")}


class SmartsTorchRLEnv(EnvBase):
    """One driving scenario as a TorchRL env (unbatched: ``batch_size == ()``).

    Multi-agent keys, with ``n = len(possible_agents)`` in ``possible_agents`` order:
    ``(group, "observation", <key>)`` [n, ...], ``(group, "action")`` [n, d], ``(group, "reward")``
    [n, 1], ``(group, "done" | "terminated" | "truncated")`` [n, 1] and ``(group, "mask")`` [n]: the
    agents still live, i.e. that act at the next step. An agent that finishes keeps its final
    observation, reward and done flags in the step where it finishes; from then on its observation
    and reward are zero, its done flags stay as they ended and its actions are ignored. The root
    ``done`` is True once no agent is live; the root ``truncated`` when the agents that finished
    last were cut off by the step limit, ``terminated`` otherwise.

    Single-agent keys: ``"observation"`` (a Composite of the observation keys), ``"action"``,
    ``"reward"`` [1], ``"done"``/``"terminated"``/``"truncated"`` [1].

    Seeding: ``set_seed(s)`` makes the following episodes use scenario seeds ``s, s + 1, ...``, so
    the same seed gives the same rollout; without it every episode uses the scenario's seed. ``s``
    is an integer from 0 to 2**64 - 1 (else ``ValueError`` naming it); the count wraps past the top.
    """

    def __init__(
        self,
        scenario: ScenarioSource = "intersection_4way_left",
        *,
        single_agent: bool | None = None,
        agent: str | None = None,
        group: str = "agents",
        device: torch.device | str = "cpu",
        **env_kwargs: Any,
    ):
        """``scenario``: a library name, a YAML path, a spec, or a built ``DrivingParallelEnv``.
        ``single_agent``: None picks flat keys exactly when the scenario has one learning agent (or
        ``agent`` is given); True keeps only ``agent`` (default: the first learning agent) and the
        social agents. ``env_kwargs`` go to ``DrivingParallelEnv`` (``observation``, ``limits``...).
        """
        super().__init__(device=device, batch_size=torch.Size([]))
        if agent is not None:
            if single_agent is False:
                raise ValueError(
                    f"agent={agent!r} picks the agent of a single-agent env; it contradicts single_agent=False"
                )
            single_agent = True
        self.env = self._build(scenario, single_agent, agent, env_kwargs)
        self.possible_agents: list[str] = list(self.env.possible_agents)
        self.single_agent = len(self.possible_agents) == 1 if single_agent is None else bool(single_agent)
        self.group = group
        self._index = {a: i for i, a in enumerate(self.possible_agents)}
        self._next_seed: int | None = None
        n = len(self.possible_agents)
        self._obs_space = self._shared_space("observation", self.env.observation_space)
        self._act_space = self._shared_space("action", self.env.action_space, bounds_may_differ=True)
        self._obs_keys = list(self._obs_space.spaces)
        self._zero_obs = {k: np.zeros(s.shape, dtype=s.dtype) for k, s in self._obs_space.spaces.items()}
        # Done flags an agent ended with; they stay set while the rest of the episode runs on.
        self._agent_terminated = np.zeros(n, dtype=bool)
        self._agent_truncated = np.zeros(n, dtype=bool)
        self._make_specs()

    # ------------------------------------------------------------------ construction
    @staticmethod
    def _build(
        scenario: ScenarioSource, single_agent: bool | None, agent: str | None, env_kwargs
    ) -> DrivingParallelEnv:
        if isinstance(scenario, DrivingParallelEnv):
            if env_kwargs:
                raise ValueError(
                    f"env keyword arguments {sorted(env_kwargs)} cannot apply to an env that is already built"
                )
            learners = scenario.possible_agents
            if single_agent and (len(learners) != 1 or (agent is not None and agent != learners[0])):
                raise ValueError(
                    f"a built env keeps all its learning agents {learners}: for a single-agent env of "
                    f"{agent or learners[0]!r}, pass the scenario instead, so the others can be left out"
                )
            return scenario
        spec = as_spec(scenario)
        learners = [a.id for a in spec.agents if not a.is_social]
        if agent is not None and agent not in learners:
            raise ValueError(f"{spec.source}: no learning agent {agent!r}; learning agents: {learners}")
        if single_agent and learners:
            chosen = agent or learners[0]
            keep = [a for a in spec.agents if a.id == chosen or a.is_social]
            spec = replace(spec, agents=keep)
        return DrivingParallelEnv(spec, **env_kwargs)

    def _shared_space(self, what: str, space_of: Callable[[str], gym.Space], bounds_may_differ: bool = False):
        """The space every agent has (one spec covers the whole agent dim, so they must agree)."""
        first_agent = self.possible_agents[0]
        first = space_of(first_agent)
        for a in self.possible_agents[1:]:
            other = space_of(a)
            if _layout(other) != _layout(first) or (not bounds_may_differ and other != first):
                raise ValueError(
                    f"{self.env.scenario.source}: agents {first_agent} and {a} have different {what} spaces "
                    f"({first} vs {other}); the TorchRL env stacks agents, so they must share one "
                    f"(use single_agent=True, or the same interface/action space for every agent)"
                )
        return first

    def _make_specs(self) -> None:
        dev = self.device
        agents = self.possible_agents
        if self.single_agent:
            obs = Composite(
                {k: space_to_spec(s, (), dev) for k, s in self._obs_space.spaces.items()}, shape=(), device=dev
            )
            self.observation_spec = Composite(observation=obs, shape=(), device=dev)
            self.action_spec = space_to_spec(self._act_space, (), dev)
            self.reward_spec = Unbounded(shape=(1,), dtype=torch.float32, device=dev)
            self.full_done_spec = Composite(_done_specs((1,), dev), shape=(), device=dev)
            return
        n = (len(agents),)
        obs = Composite({k: space_to_spec(s, n, dev) for k, s in self._obs_space.spaces.items()}, shape=n, device=dev)
        self.observation_spec = Composite(
            {self.group: Composite(observation=obs, mask=_flag_spec(n, dev), shape=n, device=dev)}, shape=(), device=dev
        )
        act = [self.env.action_space(a) for a in agents]
        low = torch.from_numpy(np.stack([np.broadcast_to(s.low, s.shape) for s in act]))
        high = torch.from_numpy(np.stack([np.broadcast_to(s.high, s.shape) for s in act]))
        if torch.isfinite(low).all() and torch.isfinite(high).all():
            action = Bounded(low=low, high=high, shape=low.shape, dtype=low.dtype, device=dev)
        else:
            action = Unbounded(shape=low.shape, dtype=low.dtype, device=dev)
        self.full_action_spec = Composite(
            {self.group: Composite(action=action, shape=n, device=dev)}, shape=(), device=dev
        )
        reward = Unbounded(shape=(*n, 1), dtype=torch.float32, device=dev)
        self.full_reward_spec = Composite(
            {self.group: Composite(reward=reward, shape=n, device=dev)}, shape=(), device=dev
        )
        self.full_done_spec = Composite(
            {**_done_specs((1,), dev), self.group: Composite(_done_specs((*n, 1), dev), shape=n, device=dev)},
            shape=(),
            device=dev,
        )

    # ------------------------------------------------------------------ seeding
    def _set_seed(self, seed: int | None) -> None:
        self._next_seed = None if seed is None else check_seed(seed, "SmartsTorchRLEnv.set_seed(seed)")

    def _take_seed(self) -> int | None:
        seed = self._next_seed
        if seed is not None:
            self._next_seed = derived_seed(seed, 1)
        return seed

    # ------------------------------------------------------------------ episode
    def _reset(self, tensordict: TensorDictBase | None = None, **kwargs) -> TensorDictBase:
        # Unbatched: torchrl only calls this when the whole episode ends, so it is a full reset.
        obs, _ = self.env.reset(seed=self._take_seed())
        self._agent_terminated[:] = False
        self._agent_truncated[:] = False
        if self.single_agent:
            out = {"observation": self._single_obs(obs), **_flags(False, False, False)}
            return TensorDict(out, batch_size=(), device=self.device)
        n = len(self.possible_agents)
        group = {"observation": self._stacked_obs(obs), "mask": self._live_mask()}
        group.update(
            _flags(np.zeros((n, 1), dtype=bool), self._agent_terminated[:, None], self._agent_truncated[:, None])
        )
        out = {self.group: TensorDict(group, batch_size=(n,), device=self.device), **_flags(False, False, False)}
        return TensorDict(out, batch_size=(), device=self.device)

    def _step(self, tensordict: TensorDictBase) -> TensorDictBase:
        env = self.env
        if self.single_agent:
            action = tensordict.get("action").detach().cpu().numpy()
            actions = {a: action for a in env.agents}
        else:
            action = tensordict.get((self.group, "action")).detach().cpu().numpy()
            index = self._index
            actions = {a: action[index[a]] for a in env.agents}
        obs, rewards, terms, truncs, _ = env.step(actions)
        all_done = not env.agents
        if self.single_agent:
            a = self.possible_agents[0]
            term = bool(terms.get(a, False))
            trunc = bool(truncs.get(a, False)) or (all_done and not term)
            out = {
                "observation": self._single_obs(obs),
                "reward": torch.from_numpy(np.array([rewards.get(a, 0.0)], dtype=np.float32)),
                **_flags(term or trunc, term, trunc),
            }
            return TensorDict(out, batch_size=(), device=self.device)
        n = len(self.possible_agents)
        rows = [self._index[a] for a in rewards]  # the agents that took part in this step
        reward = np.zeros((n, 1), dtype=np.float32)
        reward[rows, 0] = list(rewards.values())
        step_truncated = np.fromiter(truncs.values(), dtype=bool, count=len(rows))
        self._agent_terminated[rows] = np.fromiter(terms.values(), dtype=bool, count=len(rows))
        self._agent_truncated[rows] = step_truncated
        mask = self._live_mask()
        group = {"observation": self._stacked_obs(obs), "reward": torch.from_numpy(reward), "mask": mask}
        group.update(_flags(~mask.numpy()[:, None], self._agent_terminated[:, None], self._agent_truncated[:, None]))
        cut_off = all_done and bool(step_truncated.any())
        out = {
            self.group: TensorDict(group, batch_size=(n,), device=self.device),
            **_flags(all_done, all_done and not cut_off, cut_off),
        }
        return TensorDict(out, batch_size=(), device=self.device)

    # ------------------------------------------------------------------ tensors
    def _stacked_obs(self, obs: Mapping[str, Mapping[str, np.ndarray]]) -> dict[str, torch.Tensor]:
        """[n, ...] per key, zeros for agents without an observation: one stacking copy per key
        (``np.array`` of a list of rows: the result of ``np.stack`` with less overhead). A plain
        dict: the group's TensorDict takes it as a sub-TensorDict of its batch size."""
        zero = self._zero_obs
        per_agent = [obs.get(a, zero) for a in self.possible_agents]
        return {k: torch.from_numpy(np.array([o[k] for o in per_agent])) for k in self._obs_keys}

    def _single_obs(self, obs: Mapping[str, Mapping[str, np.ndarray]]) -> dict[str, torch.Tensor]:
        # Copies: the env's arrays are views into batch buffers that later steps may reuse.
        one = obs.get(self.possible_agents[0], self._zero_obs)
        return {k: torch.from_numpy(np.array(one[k])) for k in self._obs_keys}

    def _live_mask(self) -> torch.Tensor:
        mask = np.zeros(len(self.possible_agents), dtype=bool)
        mask[[self._index[a] for a in self.env.agents]] = True
        return torch.from_numpy(mask)

    def close(self, *, raise_if_closed: bool = True) -> None:
        if not self.is_closed:
            self.env.close()
        super().close(raise_if_closed=raise_if_closed)


def _flags(done, terminated, truncated) -> dict[str, torch.Tensor]:
    """Done flags as fresh bool tensors: scalars become shape [1], arrays keep their shape (copied,
    so later in-place updates of the env's state do not reach returned data)."""
    values = {"done": done, "terminated": terminated, "truncated": truncated}
    return {k: torch.from_numpy(np.array(v, dtype=bool, ndmin=1)) for k, v in values.items()}


def slot_observation_spec(obs_space: gym.spaces.Dict, k: int, device) -> Composite:
    """The spec of ``slot_observation`` for ``k`` slots of ``obs_space``."""
    obs = Composite(
        {key: space_to_spec(sp, (k,), device) for key, sp in obs_space.spaces.items()}, shape=(k,), device=device
    )
    return Composite(
        observation=obs,
        valid=Categorical(2, shape=(k, 1), dtype=torch.bool, device=device),
        agent_steps=Unbounded(shape=(k, 1), dtype=torch.float32, device=device),
        shape=(k,),
        device=device,
    )


def slot_observation(obs: dict, keys, live: np.ndarray, steps: np.ndarray) -> dict[str, Any]:
    """The per-slot part of a batched env's output: observation arrays, ``valid`` and
    ``agent_steps``, copied into fresh tensors (the env goes on updating its own arrays)."""
    return {
        "observation": {key: torch.from_numpy(obs[key].copy()) for key in keys},
        "valid": torch.from_numpy(live[:, None].copy()),
        "agent_steps": torch.from_numpy(steps[:, None].copy()),
    }


def _layout(space: gym.Space) -> Any:
    """What must match for agents to stack: the keys, shapes and dtypes (bounds may differ)."""
    if isinstance(space, gym.spaces.Dict):
        return tuple((k, _layout(s)) for k, s in space.spaces.items())
    return (type(space).__name__, getattr(space, "shape", None), str(getattr(space, "dtype", None)))


def env_factory(scenario: ScenarioSource, **kwargs: Any) -> Callable[[], SmartsTorchRLEnv]:
    """A picklable no-argument constructor (what batched envs call in each worker)."""
    if isinstance(scenario, DrivingParallelEnv):
        raise TypeError("batched envs build their own copies: pass the scenario name, path or spec, not a built env")
    return functools.partial(SmartsTorchRLEnv, scenario, **kwargs)


def make_parallel_env(
    scenario: str | Path | ScenarioSpec,
    num_workers: int,
    *,
    mp_start_method: str | None = None,
    parallel_kwargs: Mapping[str, Any] | None = None,
    **env_kwargs: Any,
) -> ParallelEnv:
    """``num_workers`` copies of the scenario, each in its own process (one SUMO per process), as a
    TorchRL ``ParallelEnv`` with batch size ``[num_workers]``. ``env_kwargs`` go to
    ``SmartsTorchRLEnv``, ``parallel_kwargs`` to ``ParallelEnv``.

    ``mp_start_method`` None keeps TorchRL's default (``spawn``: every worker imports torch and
    the simulator, seconds). ``fork`` starts workers at once, but copies this process into them:
    only use it when this process runs no SUMO and has not initialised CUDA."""
    if num_workers < 1:
        raise ValueError(f"num_workers must be at least 1, got {num_workers}")
    kwargs = dict(parallel_kwargs or {})
    if mp_start_method is not None:
        kwargs["mp_start_method"] = mp_start_method
    return ParallelEnv(num_workers, env_factory(scenario, **env_kwargs), **kwargs)


def make_serial_env(
    scenario: str | Path | ScenarioSpec,
    num_envs: int,
    **env_kwargs: Any,
) -> SerialEnv:
    """``num_envs`` copies stepped one after another in this process (for tests and debugging;
    scenarios with SUMO traffic need ``make_parallel_env`` unless ``num_envs`` is 1)."""
    if num_envs < 1:
        raise ValueError(f"num_envs must be at least 1, got {num_envs}")
    return SerialEnv(num_envs, env_factory(scenario, **env_kwargs))


class SmartsBatchedEnv(EnvBase):
    """Every learning agent of K scenario copies as one slot of a TorchRL env of batch size [slots],
    over the batched core (``smarts.env.batched.BatchedDriving``).

    For collection throughput and parameter sharing: one TensorDict per step for all slots, the
    observations built straight into [slots, ...] arrays. Each copy may run a different scenario
    (map, traffic, SUMO or built-in) with any number of learning agents; every agent of every copy
    is a slot, driven by the one shared policy. The observation spaces must agree; action spaces
    may differ (then ``action`` is [slots, widest action] and its ``Bounded`` spec bounds each
    slot's row by its own space; a narrower action reads its first columns).

    Agents of a copy finish at different times: a slot whose agent has finished *waits* (its
    observation is zeros, its actions are ignored, its reward is 0) until every agent of its copy
    has finished; the copy is then reset at once and all its slots go on from the new episode. The
    ``valid`` entry (bool [1]) says whether a slot's observation is real, i.e. whether the step
    taken from it is a real transition: training drops the others. ``agent_steps`` counts the
    steps of the slot's current episode (the episode length when ``done``).

    Seeding is ``BatchedDriving``'s: ``set_seed(s)`` makes copy ``i`` start at seed
    ``s + i * 100_003`` and count up by one per episode (modulo 2**64), so the same seed gives the
    same rollout; ``s`` is an integer from 0 to 2**64 - 1, else ``ValueError`` naming it.
    ``reward_factory`` builds one task reward per simulation (``smarts.env.task_rewards``);
    ``slots`` pads the batch with slots that never act (always invalid) up to that many, so that
    batches of different scenarios can be stacked (Ray collectors); ``options`` go to
    ``BatchedDriving`` (``observation``, ``limits``, ``lane_relative``, ``sim_device``,
    ``policy_resolver``, ``workers``, ``copy_ids``): a SUMO copy always runs in a worker process of
    its own (libsumo holds one simulation per process), ``workers`` > 0 spreads the others over
    that many processes.
    """

    def __init__(
        self,
        scenarios: Sequence[str | Path | ScenarioSpec],
        *,
        reward_factory: Callable[[], Any] | None = None,
        slots: int | None = None,
        device: torch.device | str = "cpu",
        **options: Any,
    ):
        if not scenarios:
            raise ValueError("SmartsBatchedEnv needs at least one scenario")
        built = [s for s in scenarios if isinstance(s, DrivingParallelEnv)]
        if built:
            raise TypeError(
                "SmartsBatchedEnv builds its own copies: pass scenario names, paths or specs, not a built env"
            )
        self.driving = BatchedDriving(scenarios, reward_factory=reward_factory, **options)
        n = self.driving.num_slots
        if slots is not None and slots < n:
            self.driving.close()
            raise ValueError(f"slots: {slots} is fewer than the {n} learning agents of the scenarios")
        k = n if slots is None else int(slots)
        super().__init__(device=device, batch_size=torch.Size([k]))
        self._n = n  # the slots that drive; the rest is padding
        obs_space = self.driving.observation_space
        self._keys = list(obs_space.spaces)
        self.observation_spec = slot_observation_spec(obs_space, k, device)
        self.action_spec = self._slot_action_spec(k, device)
        self.reward_spec = Unbounded(shape=(k, 1), dtype=torch.float32, device=device)
        self.full_done_spec = Composite(_done_specs((k, 1), device), shape=(k,), device=device)
        self._obs = {key: np.zeros((k, *sp.shape), dtype=sp.dtype) for key, sp in obs_space.spaces.items()}
        self._stash = {key: np.zeros_like(v) for key, v in self._obs.items()}
        self._stashed = np.zeros(k, dtype=bool)  # a first observation waits for torchrl's reset
        self._live = np.zeros(k, dtype=bool)
        self._steps = np.zeros(k, dtype=np.float32)
        self._started = False

    def _slot_action_spec(self, k: int, device) -> TensorSpec:
        """[k, width] bounded by each slot's own action space (padding rows as slot 0's: their
        actions are ignored); ``Unbounded`` if any bound is infinite."""
        d = self.driving
        low = np.concatenate([d.action_low, np.repeat(d.action_low[:1], k - self._n, axis=0)])
        high = np.concatenate([d.action_high, np.repeat(d.action_high[:1], k - self._n, axis=0)])
        if np.isfinite(low).all() and np.isfinite(high).all():
            low_t, high_t = torch.from_numpy(low), torch.from_numpy(high)
            return Bounded(low=low_t, high=high_t, shape=low.shape, dtype=low_t.dtype, device=device)
        return Unbounded(shape=low.shape, dtype=torch.float32, device=device)

    @property
    def slots(self) -> list[tuple[int, str]]:
        """``(copy, agent id)`` of every slot; padding slots are ``(-1, "")``."""
        return list(self.driving.slots) + [(-1, "")] * (self.batch_size[0] - self._n)

    def _set_seed(self, seed: int | None) -> None:
        if seed is not None:
            seed = check_seed(seed, "SmartsBatchedEnv.set_seed(seed)")
        self.driving.set_seed(seed)

    def _reset(self, tensordict: TensorDictBase | None = None, **kwargs) -> TensorDictBase:
        mask = None
        if tensordict is not None and "_reset" in tensordict.keys():
            mask = tensordict.get("_reset").reshape(-1).cpu().numpy()
        n = self._n
        if mask is None or not self._started:
            first = self.driving.reset()
            for key in self._keys:
                self._obs[key][:n] = first[key]
            self._live[:n] = True
            self._steps[:] = 0.0
            self._stashed[:] = False
            self._started = True
        else:
            slots = np.flatnonzero(mask)
            ready = slots[self._stashed[slots]]
            waiting = slots[~self._stashed[slots]]
            for key in self._keys:
                self._obs[key][ready] = self._stash[key][ready]
                self._obs[key][waiting] = 0
            self._live[ready] = True
            self._live[waiting] = False
            self._stashed[slots] = False
            self._steps[slots] = 0.0
        k = self.batch_size[0]
        zeros = torch.zeros((k, 1), dtype=torch.bool)
        out = {**self._observation(), "done": zeros, "terminated": zeros.clone(), "truncated": zeros.clone()}
        return TensorDict(out, batch_size=self.batch_size, device=self.device)

    def _step(self, tensordict: TensorDictBase) -> TensorDictBase:
        if not self._started:
            raise not_started("SmartsBatchedEnv")
        k, n = self.batch_size[0], self._n
        shape = (k, self.driving.action_width)
        actions = check_slot_actions(tensordict.get("action").detach().cpu().numpy(), shape, "SmartsBatchedEnv")
        res = self.driving.step(actions[:n])  # atomic: a refused action changes no copy
        acted = np.zeros(k, dtype=bool)
        acted[:n] = res.acted
        restarted = np.zeros(k, dtype=bool)
        restarted[:n] = res.restarted
        terminated = np.zeros(k, dtype=bool)
        terminated[:n] = res.terminated
        truncated = np.zeros(k, dtype=bool)
        truncated[:n] = res.truncated
        for key in self._keys:
            self._obs[key][:n][res.acted] = res.obs[key][res.acted]
        self._steps[acted] += 1.0
        ended = terminated | truncated
        self._live[ended] = False
        if restarted.any():
            # Slots that ended this step take their first observation at torchrl's reset; slots
            # already waiting take it now (the step that brings it is marked not valid for them).
            later = restarted & ended
            now = restarted & ~ended
            for key in self._keys:
                first = res.first[key]
                self._stash[key][later] = first[later[:n]]
                self._obs[key][now] = first[now[:n]]
            self._stashed[later] = True
            self._live[now] = True
            self._steps[now] = 0.0
        reward = np.zeros((k, 1), dtype=np.float32)
        reward[:n, 0] = res.reward
        out = {
            **self._observation(),
            "reward": torch.from_numpy(reward),
            **_flags(ended[:, None], terminated[:, None], truncated[:, None]),
        }
        return TensorDict(out, batch_size=self.batch_size, device=self.device)

    def _observation(self) -> dict[str, Any]:
        return slot_observation(self._obs, self._keys, self._live, self._steps)

    def close(self, *, raise_if_closed: bool = True) -> None:
        if not self.is_closed:
            self.driving.close()
        super().close(raise_if_closed=raise_if_closed)
