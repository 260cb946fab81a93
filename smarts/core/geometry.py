"""Small vectorised geometry helpers shared by the step loop."""

from __future__ import annotations

import math

import numpy as np

from smarts.compiled import njit

_TWO_PI = 2.0 * np.pi
_INV_TWO_PI = 1.0 / _TWO_PI


def wrap_angle(angle):
    """Wrap radians (scalar or array) to (-pi, pi]; angles already in range come back unchanged."""
    return angle + _TWO_PI * np.floor((np.pi - angle) * _INV_TWO_PI)


@njit(nogil=True, inline="always")
def wrap_scalar(angle: float) -> float:  # pragma: no cover - compiled
    """``wrap_angle`` for one float, for compiled kernels."""
    return angle + _TWO_PI * math.floor((math.pi - angle) * _INV_TWO_PI)


_FORWARD = np.array([1.0, 1.0, -1.0, -1.0])
_LEFT = np.array([1.0, -1.0, -1.0, 1.0])


def box_corners(x, y, heading, length, width) -> np.ndarray:
    """Corners float64[n, 4, 2] of boxes centred at (x, y): front-left, front-right, rear-right,
    rear-left."""
    c, s = np.cos(heading)[:, None], np.sin(heading)[:, None]
    f = (0.5 * length)[:, None] * _FORWARD
    side = (0.5 * width)[:, None] * _LEFT
    out = np.empty((len(x), 4, 2))
    out[..., 0] = c * f - s * side + x[:, None]
    out[..., 1] = s * f + c * side + y[:, None]
    return out
