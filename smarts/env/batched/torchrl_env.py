"""The batched backend as a TorchRL env of batch size [slots], with the keys of ``SmartsBatchedEnv``.

Same contract as ``smarts.env.torchrl_env.SmartsBatchedEnv`` (so a training loop takes either):
``observation`` (a Composite of the observation keys, [slots, ...]), ``action`` [slots, k],
``reward`` / ``done`` / ``terminated`` / ``truncated`` [slots, 1], ``valid`` [slots, 1] (the slot's
observation is real: the step taken from it is a transition) and ``agent_steps`` [slots, 1]. A
slot whose agent finished waits (zeros, not valid) until every agent of its copy has finished;
the copy is then reset in the same step and its slots go on. Seeds as ``SmartsBatchedEnv``.
Observations are built straight into [slots, ...] arrays and become tensors with one copy each.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import numpy as np
import torch
from tensordict import TensorDict, TensorDictBase
from torchrl.data import Composite, Unbounded
from torchrl.envs import EnvBase

from smarts.env.batched.driving import BatchedDriving
from smarts.env.torchrl_env import _done_specs, _flags, slot_observation, slot_observation_spec, space_to_spec
from smarts.scenario import ScenarioSpec


class BatchedTorchRLEnv(EnvBase):
    """``scenarios`` (one copy each) stepped by the batched backend; ``options`` go to
    ``BatchedDriving`` (``observation``, ``reward_factory``, ``lane_relative``, ``limits``)."""

    def __init__(
        self,
        scenarios: Sequence[str | Path | ScenarioSpec],
        *,
        device: torch.device | str = "cpu",
        reward_factory: Callable[[], Any] | None = None,
        **options: Any,
    ):
        self.driving = BatchedDriving(scenarios, reward_factory=reward_factory, **options)
        k = self.driving.num_slots
        super().__init__(device=device, batch_size=torch.Size([k]))
        obs_space = self.driving.observation_space
        self._keys = list(obs_space.spaces)
        self.observation_spec = slot_observation_spec(obs_space, k, device)
        self.action_spec = space_to_spec(self.driving.action_space, (k,), device)
        self.reward_spec = Unbounded(shape=(k, 1), dtype=torch.float32, device=device)
        self.full_done_spec = Composite(_done_specs((k, 1), device), shape=(k,), device=device)
        self._obs = {key: np.zeros((k, *sp.shape), dtype=sp.dtype) for key, sp in obs_space.spaces.items()}
        self._stash = {key: np.zeros_like(v) for key, v in self._obs.items()}
        self._stashed = np.zeros(k, dtype=bool)  # a first observation waits for torchrl's reset
        self._live = np.zeros(k, dtype=bool)
        self._steps = np.zeros(k, dtype=np.float32)
        self._started = False

    @property
    def slots(self) -> list[tuple[int, str]]:
        return self.driving.slots

    def _set_seed(self, seed: int | None) -> None:
        self.driving.set_seed(seed)

    def _reset(self, tensordict: TensorDictBase | None = None, **kwargs) -> TensorDictBase:
        mask = None
        if tensordict is not None and "_reset" in tensordict.keys():
            mask = tensordict.get("_reset").reshape(-1).cpu().numpy()
        if mask is None or not self._started:
            first = self.driving.reset()
            for key in self._keys:
                self._obs[key][:] = first[key]
            self._live[:] = True
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
        k = self.driving.num_slots
        zeros = torch.zeros((k, 1), dtype=torch.bool)
        out = {**self._observation(), "done": zeros, "terminated": zeros.clone(), "truncated": zeros.clone()}
        return TensorDict(out, batch_size=self.batch_size, device=self.device)

    def _step(self, tensordict: TensorDictBase) -> TensorDictBase:
        actions = tensordict.get("action").detach().cpu().numpy()
        res = self.driving.step(actions)
        acted = res.acted
        for key in self._keys:
            self._obs[key][acted] = res.obs[key][acted]
        self._steps[acted] += 1.0
        ended = res.terminated | res.truncated
        self._live[ended] = False
        if res.restarted.any():
            # Slots that ended this step take their first observation at torchrl's reset; slots
            # already waiting take it now (the step that brings it is marked not valid for them).
            later = res.restarted & ended
            now = res.restarted & ~ended
            for key in self._keys:
                self._stash[key][later] = res.first[key][later]
                self._obs[key][now] = res.first[key][now]
            self._stashed[later] = True
            self._live[now] = True
            self._steps[now] = 0.0
        out = {
            **self._observation(),
            "reward": torch.from_numpy(res.reward[:, None].copy()),
            **_flags(ended[:, None], res.terminated[:, None], res.truncated[:, None]),
        }
        return TensorDict(out, batch_size=self.batch_size, device=self.device)

    def _observation(self) -> dict[str, Any]:
        return slot_observation(self._obs, self._keys, self._live, self._steps)

    def close(self, *, raise_if_closed: bool = True) -> None:
        if not self.is_closed:
            self.driving.close()
        super().close(raise_if_closed=raise_if_closed)
