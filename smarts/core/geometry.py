"""Small vectorised geometry helpers shared by the step loop."""

from __future__ import annotations

import numpy as np


def wrap_angle(angle: np.ndarray | float) -> np.ndarray | float:
    """Wrap radians to [-pi, pi)."""
    return (np.asarray(angle) + np.pi) % (2.0 * np.pi) - np.pi


def to_local(dx: np.ndarray, dy: np.ndarray, cos_h: np.ndarray, sin_h: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Rotate world-frame offsets into a frame with heading h (x forward, y left)."""
    return cos_h * dx + sin_h * dy, -sin_h * dx + cos_h * dy
