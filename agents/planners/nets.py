"""The planners' learned parts as torch modules, and their checkpoint format.

- :class:`AIDPredictor`: AID's factorised Transformer (agent encoder with a sinusoidal time code,
  rounds of temporal then social self-attention, 3 trajectory modes with scores per neighbour),
  reduced in width and depth to train on a CPU.
- :class:`StopMoveNet`: TF's stop/move behaviour-cloning MLP (53 -> hidden^3 -> 2).
- :class:`VCRClassifier`: VCR's CNN + MLP event classifier over rasters, with a reduced head.

Checkpoints are ``{"format": "planner-net", "kind": ..., "config": {...}, "state_dict": ...,
"metrics": {...}}`` read with ``torch.load(..., weights_only=True)``.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import torch
from torch import nn

from agents.checkpoint import CheckpointError, read_checkpoint

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
        self.ffn = nn.Sequential(nn.Linear(d, ffn), nn.GELU(), nn.Dropout(dropout), nn.Linear(ffn, d), nn.Dropout(dropout))

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
            nn.Sequential(nn.Dropout(dropout), nn.Linear(d, d), nn.ELU(), nn.Linear(d, FUTURE * 3)) for _ in range(MODES)
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
        base = torch.cat([last[:, :, None, :2] + last[:, :, None, 3:5] * t[:, None],
                          last[:, :, None, 2:3].expand(-1, -1, FUTURE, 1)], dim=-1)  # [B, N, 30, 3]
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


def save_net(path: str | Path, kind: str, net: nn.Module, metrics: dict[str, Any] | None = None) -> None:
    """Write a weights-only checkpoint of one of :data:`KINDS`."""
    blob = {"format": FORMAT, "kind": kind, "config": dict(net.config),
            "state_dict": {k: v.detach().cpu() for k, v in net.state_dict().items()}, "metrics": metrics or {}}  # fmt: skip
    Path(path).parent.mkdir(parents=True, exist_ok=True)
    torch.save(blob, path)


def load_net(path: str | Path, kind: str) -> tuple[nn.Module, dict[str, Any]]:
    """The module a checkpoint holds (eval mode) and its recorded metrics; CheckpointError naming
    the file when it is not a ``kind`` checkpoint."""
    blob = read_checkpoint(path)
    if not isinstance(blob, dict) or blob.get("format") != FORMAT or blob.get("kind") != kind:
        found = blob.get("kind", blob.get("format")) if isinstance(blob, dict) else type(blob).__name__
        raise CheckpointError(f"{path}: expected a {FORMAT} checkpoint of kind {kind!r}, found {found!r}")
    net = KINDS[kind](**blob["config"])
    try:
        net.load_state_dict(blob["state_dict"])
    except RuntimeError as err:
        raise CheckpointError(f"{path}: weights do not fit the recorded config ({str(err).splitlines()[0]})") from None
    net.eval()
    return net, blob.get("metrics", {})
