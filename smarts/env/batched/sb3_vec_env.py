"""The batched backend as a Stable-Baselines3 VecEnv: one slot per learning agent of every copy.

The slot semantics are those of ``smarts.env.sb3_vec_env.SmartsVecEnv`` (so SB3's PPO sees the
same thing from either): a finishing agent's slot reports ``done`` once, with
``terminal_observation``, ``TimeLimit.truncated`` and the ``episode`` record; while the rest of
its copy drives on, the slot is inactive (zero observation, reward 0, ``info["inactive"]``); a
copy whose agents have all finished restarts within the same step and its slots get the new
episode's first observations. Seeds also follow ``SmartsVecEnv`` (see ``seed``), so both play
the same episodes.
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

from smarts.core.simulation import check_seed, derived_seed
from smarts.env.batched.driving import BatchedDriving
from smarts.scenario import ScenarioSpec


SEED_STREAM_LIMIT = 2**31 - 1  # later episodes' seeds are drawn below this, as SmartsVecEnv draws them


class BatchedVecEnv(VecEnv):
    """``scenarios`` (one copy each) stepped by the batched backend as SB3 slots.

    ``normalize_actions`` exposes ``Box(-1, 1)`` actions mapped affinely onto the agents' box (the
    scale SB3's Gaussian policies start from); ``options`` go to ``BatchedDriving``."""

    def __init__(
        self,
        scenarios: Sequence[str | Path | ScenarioSpec],
        *,
        seed: int | None = 0,
        normalize_actions: bool = False,
        **options: Any,
    ):
        self.driving = BatchedDriving(scenarios, **options)
        act_space = self.driving.action_space
        self._agent_action_space = act_space  # the agents' own box (as SmartsVecEnv keeps it)
        self.normalize_actions = normalize_actions
        if normalize_actions:
            self._act_low = act_space.low.astype(np.float64)
            self._act_half_range = (act_space.high.astype(np.float64) - self._act_low) / 2.0
            act_space = spaces.Box(-1.0, 1.0, act_space.shape, dtype=act_space.dtype)
        super().__init__(self.driving.num_slots, self.driving.observation_space, act_space)
        self.slot_agents = list(self.driving.slots)
        """``(copy index, agent id)`` of every slot."""
        n = self.num_envs
        self._returns = np.zeros(n)
        self._lengths = np.zeros(n, dtype=np.int64)
        self._started = time.perf_counter()
        self._actions: np.ndarray | None = None
        if seed is not None:
            self.seed(check_seed(seed, "BatchedVecEnv(seed=...)"))

    def seed(self, seed: int | None = None) -> Sequence[int | None]:
        """Seed the next reset as ``SmartsVecEnv`` does: slot ``i``'s seed is ``seed + i``, copy
        ``k`` starts from that of its first slot and draws each later episode's seed from a stream
        seeded by it (None: a random seed). Returns the slots' seeds."""
        if seed is None:
            seed = int(np.random.randint(0, np.iinfo(np.uint32).max, dtype=np.uint32))
        seed = check_seed(seed, "BatchedVecEnv.seed(seed)")
        first_slot: dict[int, int] = {}
        for j, (copy, _) in enumerate(self.slot_agents):
            first_slot.setdefault(copy, j)
        self._pending = {copy: derived_seed(seed, j) for copy, j in first_slot.items()}
        self._streams: dict[int, np.random.Generator] = {}
        self.driving.seed_schedule = self._episode_seed
        return [derived_seed(seed, i) for i in range(self.num_envs)]

    def _episode_seed(self, copy: int) -> int | None:
        if copy in self._pending:
            seed = self._pending.pop(copy)
            self._streams[copy] = np.random.default_rng(seed)
            return seed
        stream = self._streams.get(copy)
        return None if stream is None else int(stream.integers(SEED_STREAM_LIMIT))

    def reset(self) -> VecEnvObs:
        obs = self.driving.reset()
        self._returns[:] = 0.0
        self._lengths[:] = 0
        self.reset_infos = [{} for _ in range(self.num_envs)]
        return {k: v.copy() for k, v in obs.items()}

    def step_async(self, actions: np.ndarray) -> None:
        self._actions = np.asarray(actions)

    def step_wait(self) -> VecEnvStepReturn:
        actions = np.asarray(self._actions, dtype=np.float64).reshape(self.num_envs, -1)
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
        now = round(time.perf_counter() - self._started, 6)
        for j in np.flatnonzero(ended).tolist():
            infos[j]["TimeLimit.truncated"] = bool(res.truncated[j])
            infos[j]["terminal_observation"] = {k: v[j].copy() for k, v in obs.items()}
            infos[j]["episode"] = {"r": float(self._returns[j]), "l": int(self._lengths[j]), "t": now}
            self._returns[j] = 0.0
            self._lengths[j] = 0
        quiet = ended & ~res.restarted  # finished, its copy still driving: inactive from now on
        for k, v in obs.items():
            v[quiet] = 0
            v[res.restarted] = res.first[k][res.restarted]
        self.reset_infos = [{} for _ in range(self.num_envs)]
        return obs, rewards, ended.copy(), infos

    def close(self) -> None:
        self.driving.close()

    def get_images(self) -> Sequence[np.ndarray | None]:
        return [None] * self.num_envs

    def get_attr(self, attr_name: str, indices: VecEnvIndices = None) -> list[Any]:
        return [getattr(self.driving, attr_name)] * len(self._get_indices(indices))

    def set_attr(self, attr_name: str, value: Any, indices: VecEnvIndices = None) -> None:
        setattr(self.driving, attr_name, value)

    def env_method(self, method_name: str, *method_args, indices: VecEnvIndices = None, **method_kwargs) -> list[Any]:
        result = getattr(self.driving, method_name)(*method_args, **method_kwargs)
        return [result] * len(self._get_indices(indices))

    def env_is_wrapped(self, wrapper_class: type[gym.Wrapper], indices: VecEnvIndices = None) -> list[bool]:
        return [False] * len(self._get_indices(indices))
