"""Stable-Baselines3 adapter: every learning agent of every scenario copy is one VecEnv slot.

SB3 trains one policy over a batch of independent slots, so a multi-agent scenario maps onto it by
parameter sharing: ``num_envs`` = the learning agents of all copies, copy ``k``'s agents in
consecutive slots. The copies are stepped by the batched core (``smarts.env.batched.BatchedDriving``):
one simulation of every copy in this process, or spread over ``workers`` processes; a copy with
SUMO traffic always runs in a worker process of its own (libsumo holds one simulation per process).

Slot semantics (what SB3's PPO needs: every slot yields an observation every step):

- Actions come for every slot, as an array of exactly ``(num_envs, *action_space.shape)`` real
  numbers; those of slots whose agent is not live are ignored.
- When an agent finishes, its slot reports ``done=True`` exactly once, with
  ``info["terminal_observation"]`` (its final observation), ``info["TimeLimit.truncated"]`` (True
  when only the step limit ended it, so PPO bootstraps from the terminal observation) and
  ``info["episode"] = {"r", "l", "t"}`` (return, length, seconds), the record SB3 logs.
  ``info["events"]`` names the events of the step (``smarts.core.events``) when there are any.
- While the other agents of its copy drive on, a finished agent's slot is *inactive*: zero
  observation, reward 0, ``done=False`` and ``info["inactive"] = True``. PPO cuts GAE at the
  done, so these filler transitions never leak into the agent's real episode; they only add
  action-independent samples (their policy gradient is zero in expectation).
- When no agent of a copy is live, the copy resets within the same step (the SB3 convention):
  the slots get the new episode's first observations.

Do not wrap this in ``VecMonitor``: it would count the inactive filler steps into episode lengths.
The ``episode`` records above already feed SB3's ``ep_rew_mean``/``ep_len_mean``. Recurrent
policies would carry state from the filler into the next episode, since its first step is not
flagged as an episode start.

Seeding is ``BatchedDriving``'s, as for every adapter: ``seed(s)`` (and the constructor's
``seed``) makes copy ``i`` start its next episode at seed ``s + i * 100_003`` and count up by one
per episode (modulo 2**64). A seed is an integer from 0 to 2**64 - 1; anything else is a
``ValueError`` naming it.
"""

from __future__ import annotations

import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np
from gymnasium import spaces
from stable_baselines3.common.vec_env.base_vec_env import VecEnv, VecEnvIndices, VecEnvObs, VecEnvStepReturn

from smarts.core.errors import WorkerError
from smarts.core.events import EVENT_NAMES
from smarts.core.simulation import check_seed, derived_seed
from smarts.env.batched.driving import COPY_SEED_STRIDE, BatchedDriving, BatchedSetupError
from smarts.env.slots import check_slot_actions, not_started
from smarts.scenario import ScenarioSpec

__all__ = ["SmartsVecEnv", "WorkerError"]

ScenarioSource = str | Path | ScenarioSpec


class SmartsVecEnv(VecEnv):
    """SB3 VecEnv over ``scenarios`` (names, YAML paths or specs; one copy each), one slot per
    (copy, learning agent).

    Every slot must have one action space (one Box for one policy): slots that differ are refused,
    naming them. ``normalize_actions`` exposes ``Box(-1, 1)`` actions and maps them affinely onto
    the agents' action box, the scale SB3's Gaussian policies start from. ``options`` go to
    ``BatchedDriving``: ``observation``, ``limits``, ``lane_relative``, ``reward_factory``,
    ``sim_device``, ``policy_resolver`` and ``workers`` (0: every copy but SUMO's in this process;
    N: spread over N worker processes, each one simulation of its share)."""

    def __init__(
        self,
        scenarios: Sequence[ScenarioSource],
        *,
        seed: int | None = 0,
        normalize_actions: bool = False,
        **options: Any,
    ):
        if not scenarios:
            raise ValueError("SmartsVecEnv needs at least one scenario")
        if seed is not None:
            seed = check_seed(seed, "SmartsVecEnv(seed=...)")
        self.driving = BatchedDriving(scenarios, **options)
        try:
            act_space = self._one_action_space()
        except BaseException:
            self.driving.close()
            raise
        self._agent_action_space = act_space
        """The agents' own action box (what ``normalize_actions`` maps onto)."""
        self.normalize_actions = normalize_actions
        if normalize_actions:
            if not (np.isfinite(act_space.low).all() and np.isfinite(act_space.high).all()):
                self.driving.close()
                raise ValueError(f"normalize_actions needs a bounded Box action space, got {act_space}")
            self._act_low = act_space.low.astype(np.float64)
            self._act_half_range = (act_space.high.astype(np.float64) - self._act_low) / 2.0
            act_space = spaces.Box(-1.0, 1.0, act_space.shape, dtype=act_space.dtype)
        super().__init__(self.driving.num_slots, self.driving.observation_space, act_space)
        self.slot_agents: list[tuple[int, str]] = list(self.driving.slots)
        """``(copy index, agent id)`` of every slot."""
        n = self.num_envs
        self._returns = np.zeros(n)
        self._lengths = np.zeros(n, dtype=np.int64)
        self._clock = time.perf_counter()
        self._actions: np.ndarray | None = None
        self._started = False
        self._closed = False
        if seed is not None:
            self.seed(seed)

    @classmethod
    def from_scenario(
        cls,
        scenario: ScenarioSource,
        n_envs: int = 1,
        *,
        seed: int | None = 0,
        normalize_actions: bool = False,
        **options: Any,
    ) -> SmartsVecEnv:
        """``n_envs`` copies of one scenario (``options`` as for the constructor)."""
        if n_envs < 1:
            raise ValueError(f"n_envs must be at least 1, got {n_envs}")
        return cls([scenario] * n_envs, seed=seed, normalize_actions=normalize_actions, **options)

    def _one_action_space(self) -> spaces.Box:
        """The action space every slot shares; SB3 has one Box for one policy, so slots whose
        spaces differ are refused naming a slot of each space and its scenario."""
        d = self.driving
        if d.action_space is not None:
            return d.action_space
        first: dict[Any, int] = {}
        for j, box in enumerate(d.slot_action_spaces):
            key = (box.shape, box.low.tobytes(), box.high.tobytes())
            first.setdefault(key, j)

        def name(j: int) -> str:
            copy, agent = d.slots[j]
            return f"slot {j} (copy {copy}, {d.specs[copy].source}, {agent}): {d.slot_action_spaces[j]}"

        raise BatchedSetupError(
            "SmartsVecEnv: SB3 trains one policy with one Box action space, but the slots have "
            f"{len(first)} different ones: "
            + "; ".join(name(j) for j in first.values())
            + ". Give every learning agent the same action space (or train with SmartsBatchedEnv, "
            "whose action spec bounds each slot)"
        )

    # ------------------------------------------------------------------ VecEnv API
    def seed(self, seed: int | None = None) -> Sequence[int | None]:
        """Seed the copies' next episodes by ``BatchedDriving.set_seed``: copy ``i`` starts at
        ``seed + i * 100_003`` and counts up by one per episode. None replays each copy's scenario
        seed. Returns each slot's copy's first seed."""
        d = self.driving
        if seed is None:
            d.set_seed(None)
            return [d.specs[copy].seed for copy, _ in self.slot_agents]
        seed = check_seed(seed, "SmartsVecEnv.seed(seed)")
        d.set_seed(seed)
        return [derived_seed(seed, d.copy_ids[copy] * COPY_SEED_STRIDE) for copy, _ in self.slot_agents]

    def reset(self) -> VecEnvObs:
        obs = self.driving.reset()
        self._returns[:] = 0.0
        self._lengths[:] = 0
        self._started = True
        self.reset_infos = [{} for _ in range(self.num_envs)]
        self._reset_seeds()
        self._reset_options()
        return {k: v.copy() for k, v in obs.items()}

    def step_async(self, actions: np.ndarray) -> None:
        """Check ``actions`` (exact shape, real numbers; an ``ActionError`` naming what was
        expected); the step itself is atomic over the copies (``BatchedDriving.step``: a refused
        action changes no copy)."""
        if not self._started:
            raise not_started("SmartsVecEnv")
        self._actions = check_slot_actions(actions, (self.num_envs, *self.action_space.shape), "SmartsVecEnv")

    def step_wait(self) -> VecEnvStepReturn:
        if self._actions is None:
            raise RuntimeError("SmartsVecEnv.step_wait() without step_async(): give the actions first")
        actions, self._actions = self._actions, None
        if self.normalize_actions:
            actions = self._act_low + (np.clip(actions, -1.0, 1.0) + 1.0) * self._act_half_range
        res = self.driving.step(actions)
        obs = {k: v.copy() for k, v in res.obs.items()}
        rewards = res.reward.copy()
        ended = res.terminated | res.truncated
        infos: list[dict] = [{} for _ in range(self.num_envs)]
        self._returns[res.acted] += rewards[res.acted]
        self._lengths[res.acted] += 1
        for j in np.flatnonzero(~res.acted).tolist():
            infos[j]["inactive"] = True
        events = obs["events"]
        for j in np.flatnonzero(res.acted & events.any(axis=1)).tolist():
            infos[j]["events"] = [EVENT_NAMES[e] for e in np.flatnonzero(events[j])]
        now = round(time.perf_counter() - self._clock, 6)
        for j in np.flatnonzero(ended).tolist():
            infos[j]["TimeLimit.truncated"] = bool(res.truncated[j] and not res.terminated[j])
            infos[j]["terminal_observation"] = {k: v[j].copy() for k, v in obs.items()}
            infos[j]["episode"] = {"r": float(self._returns[j]), "l": int(self._lengths[j]), "t": now}
            self._returns[j] = 0.0
            self._lengths[j] = 0
        quiet = ended & ~res.restarted  # finished, its copy still driving: inactive from now on
        for k, v in obs.items():
            v[quiet] = 0
            v[res.restarted] = res.first[k][res.restarted]
        return obs, rewards, ended, infos

    def close(self) -> None:
        if not self._closed:
            self._closed = True
            self.driving.close()

    def get_images(self) -> Sequence[np.ndarray | None]:
        """Nothing is drawn by the batched core (render a scenario with ``DrivingParallelEnv``)."""
        return [None] * self.num_envs

    def get_attr(self, attr_name: str, indices: VecEnvIndices = None) -> list[Any]:
        """The core's attribute, once per requested slot (every slot shares the one core)."""
        return [getattr(self.driving, attr_name)] * len(self._get_indices(indices))

    def set_attr(self, attr_name: str, value: Any, indices: VecEnvIndices = None) -> None:
        setattr(self.driving, attr_name, value)

    def env_method(self, method_name: str, *method_args, indices: VecEnvIndices = None, **method_kwargs) -> list[Any]:
        """Call the core's method once; each requested slot gets its result."""
        result = getattr(self.driving, method_name)(*method_args, **method_kwargs)
        return [result] * len(self._get_indices(indices))

    def env_is_wrapped(self, wrapper_class: type[gym.Wrapper], indices: VecEnvIndices = None) -> list[bool]:
        return [False] * len(self._get_indices(indices))
