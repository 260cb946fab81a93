"""Reading a checkpoint file safely, and the error every checkpoint loader raises.

Checkpoints are plain tensors and JSON-able metadata, read with ``torch.load(...,
weights_only=True)`` so nothing in a file executes code. A missing, corrupted or foreign file is a
:class:`CheckpointError` naming the file, whichever library wrote it.
"""

from __future__ import annotations

import pickle
from pathlib import Path
from typing import Any

import torch


class CheckpointError(ValueError):
    """A checkpoint file that cannot be used; the message names the file and what is wrong."""


def read_checkpoint(path: str | Path) -> Any:
    """The object stored in ``path``, read without executing code; clear errors otherwise."""
    path = Path(path)
    if not path.is_file():
        raise CheckpointError(f"{path}: no such checkpoint file")
    try:
        return torch.load(path, map_location="cpu", weights_only=True)
    except Exception as err:  # unpickling errors come in many types
        if isinstance(err, pickle.UnpicklingError) or "weights_only" in str(err).lower():
            why = "not a torch file, or one holding Python objects; only tensors and plain data are loaded"
        else:
            lines = str(err).strip().splitlines()
            why = f"{type(err).__name__}: {lines[0] if lines else ''}"
        raise CheckpointError(f"{path}: not a readable checkpoint ({why})") from None


def checkpoint_format(blob: Any) -> str | None:
    """The ``format`` tag a checkpoint records (None when it is not a tagged dict)."""
    return blob.get("format") if isinstance(blob, dict) else None
