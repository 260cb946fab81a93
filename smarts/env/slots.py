"""What the library adapters over ``BatchedDriving`` (TorchRL's ``SmartsBatchedEnv``, SB3's
``SmartsVecEnv``) check the same way before a step reaches the simulation.

An action array is one row per slot. A wrong shape must not be reshaped into place (12 numbers for
4 slots of 3 would silently give slot 1 slot 0's second half), and text or objects must be refused
by name rather than fail deep inside numpy, so both adapters refuse them here, before anything
moves.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from smarts.core.errors import ActionError
from smarts.dynamics.action_spaces import REAL_KINDS

__all__ = ["check_slot_actions", "not_started"]


def check_slot_actions(actions: Any, shape: tuple[int, ...], owner: str) -> np.ndarray:
    """``actions`` as an array of exactly ``shape`` (slots first) with a real-number dtype, else an
    ``ActionError`` naming ``owner``'s ``actions`` and what was expected (nothing is stepped)."""
    try:
        array = np.asarray(actions)
    except (TypeError, ValueError) as err:  # ragged nested lists
        raise ActionError(
            f"{owner}: actions: expected an array of shape {shape}, got {type(actions).__name__} ({err})"
        ) from None
    if array.shape != tuple(shape):
        raise ActionError(
            f"{owner}: actions: expected shape {tuple(shape)} (one row of {shape[-1]} numbers per slot, "
            f"{shape[0]} slots), got shape {array.shape}"
        )
    if array.dtype.kind not in REAL_KINDS:
        raise ActionError(
            f"{owner}: actions: expected real numbers (an integer or float dtype), got dtype {array.dtype}"
        )
    return array


def not_started(owner: str) -> RuntimeError:
    """The error of a step before the first reset (the same words as ``DrivingParallelEnv``'s)."""
    return RuntimeError(f"{owner}.step() before reset(): call reset() first")
