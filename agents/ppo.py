"""PPO actor-critic for the simulator's dict observations, and its checkpoint format.

The observation dict is flattened in a fixed key order into one vector (``ObservationLayout``),
then an MLP gives the mean of a Gaussian over the action box (log-std is a learned vector) and a
separate MLP gives the state value. Training (``train/ppo.py``) uses torchrl's losses on these
modules; evaluation and the benchmark load a checkpoint into ``PPOPolicy`` (through
``agents.loader``), which acts with the mean action. Checkpoints are plain tensors and JSON-able
metadata, loaded with ``torch.load(..., weights_only=True)`` and validated by
:class:`PPOCheckpoint` before any network is built.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Annotated, Any, Literal

import numpy as np
import torch
from pydantic import Field, model_validator
from torch import nn
from torch.nn import functional as F

from agents.checkpoint import (
    MAX_LAYERS,
    CheckpointError,
    CheckpointSchema,
    Finite,
    Label,
    Weights,
    Width,
    check_size,
    checkpoint_format,
    mlp_size,
    read_checkpoint,
    validate_checkpoint,
    write_checkpoint,
)

CHECKPOINT_FORMAT = "smarts-ppo-v1"
MAX_ACTIONS = 16
"""The most action dimensions a checkpoint may record."""
MAX_INPUTS = 1 << 20
"""The most observation numbers a recorded layout may flatten to."""


@dataclass(frozen=True)
class ObservationLayout:
    """Which observation keys make the network input, in order, with their shapes."""

    keys: tuple[str, ...]
    shapes: tuple[tuple[int, ...], ...]

    @classmethod
    def from_space(cls, space) -> "ObservationLayout":
        keys = tuple(sorted(k for k, s in space.spaces.items() if np.issubdtype(s.dtype, np.floating)))
        return cls(keys, tuple(tuple(space.spaces[k].shape) for k in keys))

    @property
    def size(self) -> int:
        return int(sum(int(np.prod(s)) for s in self.shapes))

    def flatten(self, obs: dict) -> torch.Tensor:
        """[..., size] float32 from a dict of arrays/tensors with matching trailing shapes."""
        parts = []
        for key, shape in zip(self.keys, self.shapes):
            value = torch.as_tensor(np.asarray(obs[key]) if not torch.is_tensor(obs[key]) else obs[key])
            lead = value.shape[: value.dim() - len(shape)]
            parts.append(value.reshape(*lead, -1).float())
        return torch.cat(parts, dim=-1)


def mlp(sizes: list[int], out: int, final_gain: float = 1.0, init: bool = True) -> nn.Sequential:
    """Linear layers with tanh between them, initialised orthogonally as PPO implementations do:
    gain sqrt(2) for hidden layers, ``final_gain`` for the output (small for the actor's mean).

    The layers and their order are those of torchrl's ``MLP``, so checkpoints keep their keys and
    a seed gives the same weights; built from ``torch.nn`` directly because importing torchrl costs
    seconds in every evaluation process that only loads a checkpoint. ``init=False`` skips the
    orthogonal initialisation (a QR per layer) for networks whose weights are loaded next."""
    widths = [*sizes, out]
    layers: list[nn.Module] = []
    for i in range(len(widths) - 1):
        layers.append(nn.Linear(widths[i], widths[i + 1]))
        if i < len(widths) - 2:
            layers.append(nn.Tanh())
    net = nn.Sequential(*layers)
    if init:
        linears = [m for m in net if isinstance(m, nn.Linear)]
        for layer in linears:
            nn.init.orthogonal_(layer.weight, final_gain if layer is linears[-1] else np.sqrt(2))
            nn.init.zeros_(layer.bias)
    return net


def _forward(layers: list[tuple[torch.Tensor, torch.Tensor] | None], x: torch.Tensor) -> torch.Tensor:
    """``mlp``'s forward pass with its (weight, bias) pairs, None for each tanh: the same operations
    as calling the ``nn.Sequential``, without its per-module call overhead (thousands of one-row
    calls in a batched evaluation)."""
    for layer in layers:
        x = torch.tanh(x) if layer is None else F.linear(x, layer[0], layer[1])
    return x


class Actor(nn.Module):
    """Flat observation -> (pre-squash mean, relative spread) of the policy's Gaussian."""

    def __init__(
        self,
        obs_size: int,
        action_size: int,
        hidden: tuple[int, ...] = (128, 128),
        init_log_std: float | list[float] = -0.5,
        init: bool = True,
    ):
        super().__init__()
        self.hidden = tuple(hidden)
        self.net = mlp([obs_size, *hidden], action_size, final_gain=0.01, init=init)
        start = torch.as_tensor(init_log_std, dtype=torch.float32).expand(action_size).clone()
        self.log_std = nn.Parameter(start)

    def forward(self, x: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        loc = self.net(x)
        # A bounded spread keeps exploration alive and log-probabilities finite.
        return loc, self.log_std.clamp(-3.0, 0.5).exp().expand_as(loc)


class Critic(nn.Module):
    def __init__(self, obs_size: int, hidden: tuple[int, ...] = (128, 128)):
        super().__init__()
        self.net = mlp([obs_size, *hidden], 1, final_gain=1.0)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return self.net(x)


class ObsNormalizer(nn.Module):
    """Running mean/std of the flat observation (updated during training, frozen at test).

    Flags and masks (``raw``) pass through unchanged: normalising a 0/1 feature that is almost
    always 0 turns its rare 1 into a huge input. Every other feature is divided by its standard
    deviation, but by at least ``std_floor`` (in the feature's own units), so near-constant
    features (lane width, vehicle length) cannot blow up to the clip when they do vary. (torchrl's
    ``ObservationNorm``/``VecNorm`` transforms live in the env; this one lives in the policy, so a
    checkpoint carries its statistics to evaluation and the benchmark.)
    """

    def __init__(self, size: int, clip: float = 5.0, std_floor: float = 0.1, raw: torch.Tensor | None = None):
        super().__init__()
        self.register_buffer("mean", torch.zeros(size))
        self.register_buffer("var", torch.ones(size))
        self.register_buffer("count", torch.tensor(1e-4))
        self.register_buffer("raw", torch.zeros(size) if raw is None else torch.as_tensor(raw, dtype=torch.float32))
        self.register_buffer("std_floor", torch.tensor(float(std_floor)))
        self.register_buffer("clip_value", torch.tensor(float(clip)))

    @torch.no_grad()
    def update(self, x: torch.Tensor) -> None:
        """Fold a batch into the running statistics, in place: torchrl's losses hold references to
        these very buffers, so replacing them would leave the loss normalising with stale ones."""
        x = x.reshape(-1, x.shape[-1])
        batch_mean, n = x.mean(0), x.shape[0]
        # Two passes rather than ``x.var(0)``: torch's variance down the rows is a strided
        # reduction about 4x slower than these on a training batch (32,768 x 365).
        batch_var = (x - batch_mean).square_().mean(0)
        delta = batch_mean - self.mean
        total = self.count + n
        self.var.copy_((self.var * self.count + batch_var * n + delta**2 * self.count * n / total) / total)
        self.mean.add_(delta * n / total)
        self.count.copy_(total)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        std = torch.sqrt(self.var + 1e-8).clamp(min=float(self.std_floor))
        limit = float(self.clip_value)
        scaled = (x - self.mean).div_(std).clamp_(-limit, limit)  # in place on the one new tensor
        return torch.where(self.raw > 0, x, scaled)

    def clipped_fraction(
        self, x: torch.Tensor, normalised: torch.Tensor | None = None, rows: torch.Tensor | None = None
    ) -> float:
        """Share of the (non-raw) normalised inputs that sit at the clip: a health check
        (``normalised``: ``self(x)`` when the caller has it already; ``rows``: only these rows of
        ``[N, D]`` inputs count)."""
        keep = self.raw <= 0
        if not bool(keep.any()):
            return 0.0
        if normalised is None:
            std = torch.sqrt(self.var + 1e-8).clamp(min=float(self.std_floor))
            normalised = (x - self.mean) / std
        normalised = normalised.reshape(-1, keep.numel())
        if rows is not None:
            normalised = normalised[rows]
        at_clip = (normalised.abs() >= float(self.clip_value)) & keep
        return float(at_clip.sum()) / max(normalised.shape[0] * int(keep.sum()), 1)

    def load_state_dict(self, state_dict, strict: bool = True, assign: bool = False):
        """Checkpoints written before flags and the std floor existed normalise every feature."""
        state = dict(state_dict)
        if "raw" not in state:
            state["raw"] = torch.zeros_like(state["mean"])
            state["std_floor"] = torch.tensor(0.0)
            state["clip_value"] = torch.tensor(10.0)
        return super().load_state_dict(state, strict=strict, assign=assign)


MEAN_MAPS = ("linear", "tanh")
"""How the actor's output becomes the action mean: ``linear`` maps [-1, 1] onto [low, high] and the
deterministic action is clipped to the box; ``tanh`` (checkpoints of earlier versions) squashes it."""


def scale_action(pre: torch.Tensor, low: torch.Tensor, high: torch.Tensor, mean_map: str = "linear") -> torch.Tensor:
    """The mean of the policy's Gaussian in action units: the actor's output mapped onto [low, high].

    ``linear`` (the default) leaves it unbounded, so a mean pushed past the box still gets
    gradients and can come back (a tanh squash saturates there and sticks); the simulator clips
    the actions it receives."""
    if mean_map == "tanh":
        pre = torch.tanh(pre)
    return low + (pre + 1.0) * 0.5 * (high - low)


# ------------------------------------------------------------------------------ checkpoint schema
Shape = Annotated[list[Width], Field(max_length=8)]
"""An observation's shape: up to 8 dimensions of 1 to MAX_WIDTH."""


class LayoutSchema(CheckpointSchema):
    """The observation keys the network reads, in order, and their shapes."""

    keys: Annotated[list[Label], Field(min_length=1, max_length=256)]
    shapes: Annotated[list[Shape], Field(min_length=1, max_length=256)]

    @model_validator(mode="after")
    def _consistent(self) -> "LayoutSchema":
        if len(self.keys) != len(self.shapes):
            raise ValueError(f"{len(self.keys)} keys but {len(self.shapes)} shapes; expected one shape per key")
        if len(set(self.keys)) != len(self.keys):
            raise ValueError(f"keys repeat: {self.keys}")
        size = sum(int(np.prod(s)) for s in self.shapes)
        if size > MAX_INPUTS:
            raise ValueError(f"the shapes flatten to {size:,} inputs; at most {MAX_INPUTS:,}")
        return self


class ActionSchema(CheckpointSchema):
    """How the policy's actions drive a vehicle, and their box (finite, ``low <= high``)."""

    space: Label
    controller: Label = "direct"
    mean: Literal["linear", "tanh"] = "tanh"  # checkpoints of earlier versions squash with tanh
    low: Annotated[list[Finite], Field(min_length=1, max_length=MAX_ACTIONS)]
    high: Annotated[list[Finite], Field(min_length=1, max_length=MAX_ACTIONS)]

    @model_validator(mode="after")
    def _box(self) -> "ActionSchema":
        if len(self.low) != len(self.high):
            raise ValueError(f"low has {len(self.low)} numbers, high {len(self.high)}; expected one pair per dimension")
        if any(lo > hi for lo, hi in zip(self.low, self.high)):
            raise ValueError(f"low {self.low} exceeds high {self.high}; expected low <= high in every dimension")
        return self


Hidden = Annotated[list[Width], Field(min_length=1, max_length=MAX_LAYERS)]
"""Hidden layer widths: 1 to MAX_LAYERS layers of 1 to MAX_WIDTH units."""


class PPOCheckpoint(CheckpointSchema):
    """A ``smarts-ppo-v1`` file: networks, observation statistics, layout, action box and the
    settings it was trained with (``interface`` and ``lane_relative`` are plain data the simulator
    validates where it builds the env)."""

    format: Literal["smarts-ppo-v1"]
    actor: Weights
    critic: Weights
    normalizer: Weights
    layout: LayoutSchema
    action: ActionSchema
    hidden: Hidden
    interface: Any = None
    lane_relative: Any = None
    comms: Any = None
    config: dict[str, Any] = {}
    step: Annotated[int, Field(ge=0)]
    metrics: dict[str, float] = {}
    optimizer: dict[str, Any] | None = None


def size_of(layout: LayoutSchema) -> int:
    return int(sum(int(np.prod(s)) for s in layout.shapes))


def save_checkpoint(path: Path, *, actor: Actor, critic: Critic, normalizer: ObsNormalizer,
                    layout: ObservationLayout, low: np.ndarray, high: np.ndarray,
                    action_space: str, config: dict, step: int, metrics: dict,
                    optimizer_state: dict | None = None, controller: str = "direct",
                    interface: dict | None = None, lane_relative: dict | None = None,
                    comms: dict | None = None) -> Path:  # fmt: skip
    """Write tensors + JSON-able metadata atomically (``weights_only`` loadable).

    ``action_space`` and ``controller`` say how the actions drive a vehicle and ``interface`` (the
    plain-data form of ``smarts.sensors.interface.AgentInterface``) which observation the policy
    reads, so evaluation and the benchmark build the env this policy was trained in (and validate
    the interface, ``lane_relative`` and ``comms`` (V2V) settings there)."""
    blob = {
        "format": CHECKPOINT_FORMAT,
        # CPU tensors whatever device trained them: evaluation loads them anywhere.
        "actor": {k: v.cpu() for k, v in actor.state_dict().items()},
        "critic": {k: v.cpu() for k, v in critic.state_dict().items()},
        "normalizer": {k: v.cpu() for k, v in normalizer.state_dict().items()},
        "layout": {"keys": list(layout.keys), "shapes": [list(s) for s in layout.shapes]},
        "action": {
            "space": action_space,
            "controller": controller,
            "mean": "linear",
            "low": [float(v) for v in low],
            "high": [float(v) for v in high],
        },
        "interface": interface,
        "lane_relative": lane_relative,
        "comms": comms,
        "hidden": list(config.get("hidden", (128, 128))),
        "config": config,
        "step": int(step),
        "metrics": {k: float(v) for k, v in metrics.items()},
    }
    if optimizer_state is not None:
        blob["optimizer"] = optimizer_state
    return write_checkpoint(blob, path)


def check_checkpoint(blob: Any, path: str | Path) -> dict:
    """``blob`` if it is a valid PPO checkpoint (:class:`PPOCheckpoint`, and networks of at most
    ``MAX_PARAMETERS``); :class:`CheckpointError` naming ``path`` and the field otherwise."""
    found = checkpoint_format(blob)
    if found != CHECKPOINT_FORMAT:
        shown = found if isinstance(blob, dict) else type(blob).__name__
        raise CheckpointError(f"{path}: expected a {CHECKPOINT_FORMAT} checkpoint, found {shown!r}")
    checked = validate_checkpoint(PPOCheckpoint, blob, path)
    inputs, actions = size_of(checked.layout), len(checked.action.low)
    # actor (with its log-std), critic and observation statistics
    check_size(mlp_size([inputs, *checked.hidden], actions) + actions + mlp_size([inputs, *checked.hidden], 1)
               + 4 * inputs, path, "hidden")  # fmt: skip
    return blob


def load_checkpoint(path: Path) -> dict:
    """Read a PPO checkpoint with ``weights_only=True``; a corrupted or foreign file is a clear error."""
    return check_checkpoint(read_checkpoint(path), path)


class PPOPolicy:
    """A trained PPO actor as a batched policy (``act(obs) -> actions``), for eval and the zoo.

    ``interface`` and ``lane_relative`` are the recorded plain data (None: the scenario's
    interface, the default settings); ``source`` names the file for error messages."""

    batching = "episodes"  # no state, but a matrix product rounds by batch size: one call per episode

    def __init__(self, blob: dict, source: str = "<checkpoint>"):
        check_checkpoint(blob, source)  # every field, and the network's size, before it is built
        layout = ObservationLayout(tuple(blob["layout"]["keys"]), tuple(tuple(s) for s in blob["layout"]["shapes"]))
        self.layout = layout
        self.action_space = blob["action"]["space"]
        self.controller = blob["action"].get("controller", "direct")
        self.mean_map = blob["action"].get("mean", "tanh")
        # Plain data, validated by the simulator where it builds the env (agents import no simulator).
        self.interface = blob.get("interface")
        self.lane_relative = blob.get("lane_relative")
        self.comms = blob.get("comms")
        self.source = source
        self.low = torch.tensor(blob["action"]["low"], dtype=torch.float32)
        self.high = torch.tensor(blob["action"]["high"], dtype=torch.float32)
        self.actor = Actor(layout.size, len(self.low), tuple(blob["hidden"]), init=False)  # weights next
        self.normalizer = ObsNormalizer(layout.size)
        try:
            self.actor.load_state_dict(blob["actor"])
            self.normalizer.load_state_dict(blob["normalizer"])
        except RuntimeError as err:
            raise CheckpointError(f"{source}: weights do not match the recorded layout ({err})") from None
        self.actor.eval()

    @classmethod
    def load(cls, path: str | Path) -> "PPOPolicy":
        return cls(read_checkpoint(Path(path)), str(path))

    def check_space(self, space) -> None:
        """The env's observation space must have every key the policy reads, with its shape."""
        for key, shape in zip(self.layout.keys, self.layout.shapes):
            if key not in space.spaces or tuple(space.spaces[key].shape) != shape:
                got = tuple(space.spaces[key].shape) if key in space.spaces else "missing"
                raise CheckpointError(f"observation {key!r}: policy expects shape {shape}, env has {got}")

    @torch.no_grad()
    def act(self, obs: dict) -> np.ndarray:
        x = self.normalizer(self.layout.flatten(obs))
        return self._actions(x).numpy()

    def _actions(self, x: torch.Tensor) -> torch.Tensor:
        loc, _ = self.actor(x)
        action = scale_action(loc, self.low, self.high, self.mean_map)
        return torch.minimum(torch.maximum(action, self.low), self.high)

    @torch.no_grad()
    def act_episodes(self, obs: dict, counts: list[int]) -> np.ndarray:
        """``act`` of several episodes at once, bit for bit: ``obs`` holds their rows stacked
        (``counts[i]`` rows of episode ``i``, in order). Flattening and normalising go element by
        element, so they run on all rows together; the network then sees each episode's rows as
        ``act`` would (a matrix product's rounding depends on how many rows it holds)."""
        x = self.normalizer(self.layout.flatten(obs))
        layers = [(m.weight, m.bias) if isinstance(m, nn.Linear) else None for m in self.actor.net]
        loc = torch.cat([_forward(layers, part) for part in torch.split(x, list(counts))])
        action = scale_action(loc, self.low, self.high, self.mean_map)  # element by element: all rows
        return torch.minimum(torch.maximum(action, self.low), self.high).numpy()
