"""Stable-Baselines3 PPO policies exported by ``python -m train ppo --lib sb3``, as batched policies.

The export holds the SB3 policy's tensors, the observation keys and shapes it reads, its action box
and the settings it was trained with (action space, controller, observation interface and
lane-relative settings as plain data). Loading needs Stable-Baselines3 (which built the network)
but nothing of the trainer, so evaluation and the benchmark load it like the torchrl checkpoints.
"""

from __future__ import annotations

from typing import Annotated, Any, Literal

import numpy as np
import torch
from pydantic import Field

from agents.checkpoint import (
    CheckpointError,
    CheckpointSchema,
    Label,
    Weights,
    check_size,
    mlp_size,
    validate_checkpoint,
)
from agents.ppo import MAX_INPUTS, ActionSchema, Hidden, Shape

SB3_FORMAT = "smarts-sb3-ppo-v1"


class SB3Checkpoint(CheckpointSchema):
    """An exported SB3 policy: its tensors, the observation keys and shapes it reads, the action box
    and the settings it was trained with (``interface`` and ``lane_relative`` are plain data the
    simulator validates)."""

    format: Literal["smarts-sb3-ppo-v1"]
    policy: Weights
    observation: Annotated[dict[Label, Shape], Field(min_length=1, max_length=256)]
    action: ActionSchema
    net_arch: Hidden
    interface: Any = None
    lane_relative: Any = None
    comms: Any = None
    config: dict[str, Any] = {}
    step: Annotated[int, Field(ge=0)]
    n_updates: Annotated[int, Field(ge=0)] = 0
    metrics: dict[str, float] = {}
    optimizer: dict[str, Any] | None = None


def check_export(blob: Any, source: str) -> SB3Checkpoint:
    """``blob`` validated as :class:`SB3Checkpoint`, its networks' size checked before they are
    built; :class:`CheckpointError` naming ``source`` and the field otherwise."""
    checked = validate_checkpoint(SB3Checkpoint, blob, source)
    inputs = sum(int(np.prod(shape)) for shape in checked.observation.values())
    if inputs > MAX_INPUTS:
        raise CheckpointError(f"{source}: observation: the shapes flatten to {inputs:,} inputs; at most {MAX_INPUTS:,}")
    actions = len(checked.action.low)
    check_size(mlp_size([inputs, *checked.net_arch], actions) + actions + mlp_size([inputs, *checked.net_arch], 1),
               source, "net_arch")  # fmt: skip
    return checked


class SB3Policy:
    """An exported SB3 PPO policy acting deterministically on batched observations.

    ``interface`` and ``lane_relative`` are the recorded plain data (None: the scenario's
    interface, the default settings); the simulator validates them when it builds the env."""

    batching = "episodes"  # no state, but a matrix product rounds by batch size: one call per episode

    def __init__(self, blob: dict[str, Any], source: str = "<checkpoint>"):
        import gymnasium as gym
        from stable_baselines3.common.policies import MultiInputActorCriticPolicy

        check_export(blob, source)
        self.source = source
        obs_space = gym.spaces.Dict(
            {k: gym.spaces.Box(-np.inf, np.inf, tuple(shape), np.float32) for k, shape in blob["observation"].items()}
        )
        self.low = np.asarray(blob["action"]["low"], dtype=np.float32)
        self.high = np.asarray(blob["action"]["high"], dtype=np.float32)
        self.action_space = blob["action"]["space"]
        self.controller = blob["action"].get("controller", "direct")
        self.interface = blob.get("interface")
        self.lane_relative = blob.get("lane_relative")
        self.comms = blob.get("comms")
        act_space = gym.spaces.Box(-1.0, 1.0, self.low.shape, np.float32)
        self.policy = MultiInputActorCriticPolicy(obs_space, act_space, lambda _: 0.0, net_arch=blob["net_arch"])
        try:
            self.policy.load_state_dict(blob["policy"])
        except RuntimeError as err:
            raise CheckpointError(
                f"{source}: weights do not match the recorded observation and layers ({err})"
            ) from None
        self.policy.eval()
        self.keys = list(blob["observation"])

    @torch.no_grad()
    def act(self, obs: dict) -> np.ndarray:
        action, _ = self.policy.predict({k: np.asarray(obs[k]) for k in self.keys}, deterministic=True)
        action = np.clip(action, -1.0, 1.0)
        return self.low + (action + 1.0) * 0.5 * (self.high - self.low)
