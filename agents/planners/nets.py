"""The planners' learned parts as torch modules, and their checkpoint format.

- :class:`AIDPredictor`: AID's factorised Transformer (agent encoder with a sinusoidal time code,
  rounds of temporal then social self-attention, 3 trajectory modes with scores per neighbour),
  reduced in width and depth to train on a CPU.
- :class:`StopMoveNet`: TF's stop/move behaviour-cloning MLP (53 -> hidden^3 -> 2).
- :class:`VCRClassifier`: VCR's CNN + MLP event classifier over rasters, with a reduced head.

Checkpoints are ``{"format": "planner-net", "kind": ..., "config": {...}, "state_dict": ...,
"metrics": {...}}`` read with ``torch.load(..., weights_only=True)``; :data:`SCHEMAS` validates each
kind's file (its config's every field within bounds, finite weights) before the network is built.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Annotated, Any, Literal

import torch
from pydantic import Field, model_validator
from torch import nn

from agents.checkpoint import (
    MAX_LAYERS,
    CheckpointError,
    CheckpointSchema,
    Metrics,
    Weights,
    Width,
    check_size,
    mlp_size,
    read_checkpoint,
    validate_checkpoint,
    write_checkpoint,
)

FORMAT = "planner-net"
HISTORY, FUTURE, NEIGHBOURS, MODES = 11, 30, 5, 3


class AgentEncoder(nn.Module):
    """Per-step features (x, y, heading, vx, vy) -> d-dim, plus a fixed sinusoidal time code."""

    def __init__(self, d: int, dropout: float):
        super().__init__()
        self.position = nn.Sequential(nn.Linear(5, d // 2), nn.ReLU(), nn.Linear(d // 2, d))
        pe = torch.zeros(HISTORY, d)
        pos = torch.arange(HISTORY, dtype=torch.float32)[:, None]
        div = torch.exp(torch.arange(0, d, 2, dtype=torch.float32) * (-math.log(10000.0) / d))
        pe[:, 0::2], pe[:, 1::2] = torch.sin(pos * div), torch.cos(pos * div)
        self.register_buffer("pe", pe[None], persistent=True)
        self.dropout = nn.Dropout(dropout)

    def forward(self, x: torch.Tensor) -> torch.Tensor:  # [B, T, 5] -> [B, T, d]
        return self.dropout(self.position(x) + self.pe)


class Block(nn.Module):
    """Self-attention with a key-padding mask, then a feed-forward layer; residuals + LayerNorm."""

    def __init__(self, d: int, heads: int, ffn: int, dropout: float):
        super().__init__()
        self.self_attention = nn.MultiheadAttention(d, heads, dropout=dropout, batch_first=True)
        self.norm_1, self.norm_2 = nn.LayerNorm(d), nn.LayerNorm(d)
        self.ffn = nn.Sequential(
            nn.Linear(d, ffn), nn.GELU(), nn.Dropout(dropout), nn.Linear(ffn, d), nn.Dropout(dropout)
        )

    def forward(self, x: torch.Tensor, pad: torch.Tensor) -> torch.Tensor:
        attended, _ = self.self_attention(x, x, x, key_padding_mask=pad)
        x = self.norm_1(x + attended)
        return self.norm_2(x + self.ffn(x))


class AIDPredictor(nn.Module):
    """ego [B, 11, 5], neighbours [B, 5, 11, 5] (ego frame at the last step; all-zero rows are
    padding) -> trajectories [B, 5, 3, 30, 3] (x, y, heading) and mode scores [B, 5, 3]."""

    def __init__(self, d: int = 128, heads: int = 4, ffn: int = 256, rounds: int = 2, dropout: float = 0.1):
        super().__init__()
        self.config = {"d": d, "heads": heads, "ffn": ffn, "rounds": rounds, "dropout": dropout}
        self.agent_encoder = AgentEncoder(d, dropout)
        self.time_blocks = nn.ModuleList(Block(d, heads, ffn, dropout) for _ in range(rounds))
        self.agent_blocks = nn.ModuleList(Block(d, heads, ffn, dropout) for _ in range(rounds))
        self.decoders = nn.ModuleList(
            nn.Sequential(nn.Dropout(dropout), nn.Linear(d, d), nn.ELU(), nn.Linear(d, FUTURE * 3))
            for _ in range(MODES)
        )
        self.encode = nn.Linear(FUTURE * 3, d)
        self.scorers = nn.ModuleList(
            nn.Sequential(nn.Dropout(dropout), nn.Linear(2 * d, d), nn.ELU(), nn.Linear(d, 1)) for _ in range(MODES)
        )

    def forward(self, ego: torch.Tensor, neighbours: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        actors = torch.cat([ego[:, None], neighbours], dim=1)  # [B, A, T, 5]
        B, A, T, _ = actors.shape
        pad = actors.abs().sum(-1) == 0  # [B, A, T]
        pad = pad.clone()
        pad[:, :, -1] = False  # never mask a whole sequence (the original's in-place quirk, kept)
        pad[:, 0] = False
        x = self.agent_encoder(actors.reshape(B * A, T, 5))
        for time_block, agent_block in zip(self.time_blocks, self.agent_blocks):
            x = time_block(x, pad.reshape(B * A, T))
            x = x.reshape(B, A, T, -1).transpose(1, 2).reshape(B * T, A, -1)
            x = agent_block(x, pad.transpose(1, 2).reshape(B * T, A))
            x = x.reshape(B, T, A, -1).transpose(1, 2).reshape(B * A, T, -1)
        feature = x.reshape(B, A, T, -1)[:, 1:, -1]  # neighbours at the last step [B, N, d]
        # Offsets are added to the constant-velocity extrapolation of each neighbour's last state
        # (the original added them to its current pose); a small CPU budget learns the residual.
        last = neighbours[:, :, -1]  # [B, N, 5]: x, y, heading, vx, vy
        t = torch.arange(1, FUTURE + 1, dtype=last.dtype, device=last.device) * 0.1
        base = torch.cat(
            [
                last[:, :, None, :2] + last[:, :, None, 3:5] * t[:, None],
                last[:, :, None, 2:3].expand(-1, -1, FUTURE, 1),
            ],
            dim=-1,
        )  # [B, N, 30, 3]
        trajs, scores = [], []
        for decoder, scorer in zip(self.decoders, self.scorers):
            offsets = decoder(feature)  # [B, N, 90]
            trajs.append(offsets.reshape(B, -1, FUTURE, 3) + base)
            scores.append(scorer(torch.cat([feature, self.encode(offsets.detach())], dim=-1)))
        return torch.stack(trajs, dim=2), torch.cat(scores, dim=-1)


class StopMoveNet(nn.Module):
    """TF's behaviour-cloning MLP: 53 features -> logits (0 stop, 1 move)."""

    def __init__(self, hidden: int = 256, layers: int = 3, inputs: int = 53):
        super().__init__()
        self.config = {"hidden": hidden, "layers": layers, "inputs": inputs}
        mods: list[nn.Module] = []
        width = inputs
        for _ in range(layers):
            mods += [nn.Linear(width, hidden), nn.ReLU()]
            width = hidden
        mods.append(nn.Linear(width, 2))
        self.net = nn.Sequential(*mods)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return self.net(x)


class VCRClassifier(nn.Module):
    """VCR's event classifier with a reduced head: rasters uint8 [B, C, 64, 64] and 24 numbers
    (``agents.planners.vcr.classifier_numbers``: the step, the next 5 path points, the ego's speed
    and the nearest car ahead, ego frame) -> 6 event logits (0 collision ... 5 safe)."""

    def __init__(self, channels: int = 3, size: int = 64, numbers: int = 24, classes: int = 6):
        super().__init__()
        self.config = {"channels": channels, "size": size, "numbers": numbers, "classes": classes}
        blocks: list[nn.Module] = []
        width, side = channels, size
        for _ in range(4):
            blocks += [nn.Conv2d(width, 32, 3, stride=2), nn.BatchNorm2d(32), nn.ReLU()]
            width, side = 32, (side - 3) // 2 + 1
        self.image = nn.Sequential(*blocks, nn.Flatten())
        self.numbers = nn.Sequential(nn.Linear(numbers, 64), nn.ReLU(), nn.Dropout(0.5))
        self.head = nn.Sequential(nn.Linear(32 * side * side + 64, 256), nn.ReLU(), nn.Dropout(0.5),
                                  nn.Linear(256, 64), nn.ReLU(), nn.Linear(64, classes))  # fmt: skip

    def forward(self, rasters: torch.Tensor, numbers: torch.Tensor) -> torch.Tensor:
        image = (rasters.float() - 0.5) / 0.5  # layers are 0/1 masks
        return self.head(torch.cat([self.image(image), self.numbers(numbers)], dim=-1))


KINDS: dict[str, type[nn.Module]] = {
    "aid-predictor": AIDPredictor, "tf-stop-move": StopMoveNet, "vcr-classifier": VCRClassifier,
}  # fmt: skip

Dropout = Annotated[float, Field(ge=0.0, lt=1.0, allow_inf_nan=False)]


class AIDConfig(CheckpointSchema):
    d: Annotated[int, Field(ge=2, le=1024)]
    heads: Annotated[int, Field(ge=1, le=64)]
    ffn: Width
    rounds: Annotated[int, Field(ge=1, le=MAX_LAYERS)]
    dropout: Dropout

    @model_validator(mode="after")
    def _divisible(self) -> "AIDConfig":
        if self.d % 2 or self.d % self.heads:  # the time code interleaves sin/cos; heads split d
            raise ValueError(f"d ({self.d}) must be even and a multiple of heads ({self.heads})")
        return self

    def parameters(self) -> int:
        """Numbers (parameters and buffers) of :class:`AIDPredictor` of this config, unbuilt."""
        d, ffn, half = self.d, self.ffn, self.d // 2
        encoder = mlp_size([5, half], d) + HISTORY * d
        block = 4 * d * d + 4 * d + 4 * d + mlp_size([d, ffn], d)  # attention, two norms, feed-forward
        heads = MODES * (mlp_size([d, d], FUTURE * 3) + mlp_size([2 * d, d], 1)) + (FUTURE * 3 + 1) * d
        return encoder + 2 * self.rounds * block + heads


class StopMoveConfig(CheckpointSchema):
    hidden: Width
    layers: Annotated[int, Field(ge=1, le=MAX_LAYERS)]
    inputs: Width

    def parameters(self) -> int:
        """Numbers of :class:`StopMoveNet` of this config, unbuilt."""
        return mlp_size([self.inputs] + [self.hidden] * self.layers, 2)


class VCRConfig(CheckpointSchema):
    channels: Annotated[int, Field(ge=1, le=64)]
    size: Annotated[int, Field(ge=31, le=512)]  # four stride-2 3x3 convolutions leave at least one cell
    numbers: Width
    classes: Annotated[int, Field(ge=2, le=64)]

    def parameters(self) -> int:
        """Numbers (parameters and batch-norm statistics) of :class:`VCRClassifier`, unbuilt."""
        side, convs = self.size, 0
        for width in (self.channels, 32, 32, 32):
            convs += width * 32 * 9 + 32 + 4 * 32 + 1
            side = (side - 3) // 2 + 1
        return convs + mlp_size([self.numbers], 64) + mlp_size([32 * side * side + 64, 256, 64], self.classes)


class PlannerCheckpoint(CheckpointSchema):
    """A ``planner-net`` file; each kind's subclass fixes ``kind`` and the type of ``config``."""

    format: Literal["planner-net"]
    kind: str
    config: AIDConfig | StopMoveConfig | VCRConfig
    state_dict: Weights
    metrics: Metrics = {}


class AIDCheckpoint(PlannerCheckpoint):
    kind: Literal["aid-predictor"]
    config: AIDConfig


class StopMoveCheckpoint(PlannerCheckpoint):
    kind: Literal["tf-stop-move"]
    config: StopMoveConfig


class VCRCheckpoint(PlannerCheckpoint):
    kind: Literal["vcr-classifier"]
    config: VCRConfig


SCHEMAS: dict[str, type[PlannerCheckpoint]] = {
    "aid-predictor": AIDCheckpoint, "tf-stop-move": StopMoveCheckpoint, "vcr-classifier": VCRCheckpoint,
}  # fmt: skip
"""kind -> the schema of its checkpoint file."""


def save_net(path: str | Path, kind: str, net: nn.Module, metrics: dict[str, Any] | None = None) -> None:
    """Write a weights-only checkpoint of one of :data:`KINDS` (atomically: a failed write leaves
    the previous file)."""
    blob = {"format": FORMAT, "kind": kind, "config": dict(net.config),
            "state_dict": {k: v.detach().cpu() for k, v in net.state_dict().items()}, "metrics": metrics or {}}  # fmt: skip
    write_checkpoint(blob, path)


def load_net(path: str | Path, kind: str) -> tuple[nn.Module, dict[str, Any]]:
    """The module a checkpoint holds (eval mode) and its recorded metrics; CheckpointError naming
    the file (and the field) when it is not a valid ``kind`` checkpoint. The file is validated and
    the network's size checked before the network is built."""
    blob = read_checkpoint(path)
    if not isinstance(blob, dict) or blob.get("format") != FORMAT or blob.get("kind") != kind:
        found = blob.get("kind", blob.get("format")) if isinstance(blob, dict) else type(blob).__name__
        raise CheckpointError(f"{path}: expected a {FORMAT} checkpoint of kind {kind!r}, found {found!r}")
    checked = validate_checkpoint(SCHEMAS[kind], blob, path)
    check_size(checked.config.parameters(), path)
    net = KINDS[kind](**checked.config.model_dump())
    try:
        net.load_state_dict(checked.state_dict)
    except RuntimeError as err:
        raise CheckpointError(f"{path}: weights do not fit the recorded config ({str(err).splitlines()[0]})") from None
    net.eval()
    return net, dict(checked.metrics)
