"""The batched policy a checkpoint file holds, whichever library trained it.

The file's ``format`` tag picks the loader: torchrl PPO checkpoints (``agents.ppo``) or exported
Stable-Baselines3 policies (``agents.sb3_policy``). The zoo and the benchmark load files through
here, so a new format needs one entry in :data:`LOADERS`.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any, Callable

from agents.checkpoint import CheckpointError, checkpoint_format, read_checkpoint
from agents.ppo import CHECKPOINT_FORMAT, PPOPolicy
from agents.sb3_policy import SB3_FORMAT, SB3Policy


def _ppo(blob: dict, path: Path) -> PPOPolicy:
    return PPOPolicy(blob, str(path))


def _sb3(blob: dict, path: Path) -> SB3Policy:
    return SB3Policy(blob, str(path))


LOADERS: dict[str, Callable[[dict, Path], Any]] = {CHECKPOINT_FORMAT: _ppo, SB3_FORMAT: _sb3}
"""format tag -> loader(blob, path)."""


def load_policy_file(path: str | Path) -> PPOPolicy | SB3Policy:
    """Read ``path`` (``weights_only``) and build its policy; :class:`CheckpointError` naming the
    file when it is missing, unreadable, of another format or inconsistent."""
    path = Path(path)
    blob = read_checkpoint(path)
    found = checkpoint_format(blob)
    if found not in LOADERS:
        shown = found if found is not None else type(blob).__name__
        raise CheckpointError(f"{path}: expected a checkpoint of format {' or '.join(LOADERS)}, found {shown!r}")
    return LOADERS[found](blob, path)
