"""Kinematic bicycle model, vectorised over vehicles.

State (x, y, heading, speed), inputs (longitudinal acceleration, front wheel steering angle). The
rear axle moves along its heading and the path curvature is ``tan(steer) / wheelbase``. For inputs
held constant over ``dt`` the path is a circular arc whatever the speed profile, so the step is
integrated exactly (no substeps): the arc length comes from the speed ramp (which stops at zero
speed, never reversing) and the displacement is the chord of that arc. Any point on the car's centre
line can be the reference point via ``ref_ahead`` (its distance ahead of the rear axle; every such
point has the same speed along the heading, so ``speed`` does not depend on it).
"""

from __future__ import annotations

import numpy as np

from smarts.core.geometry import wrap_angle

# Wheelbase as a fraction of the overall length when a vehicle type does not say (sedan: 2.7 / 4.5).
WHEELBASE_FRACTION = 0.6

_TINY = 1.0e-300  # sin(x) == x exactly for |x| this small


def wheelbase_for_length(length):
    """A plausible wheelbase, m, for a vehicle of the given overall length."""
    return WHEELBASE_FRACTION * np.asarray(length, dtype=np.float64)


def steering_for_curvature(curvature, wheelbase):
    """Front wheel angle, rad, that makes the rear axle follow a path of the given curvature."""
    return np.arctan(curvature * wheelbase)


def curvature_for_steering(steer, wheelbase):
    """Path curvature, 1/m, of the rear axle for a front wheel angle (+ = left)."""
    return np.tan(steer) / wheelbase


def bicycle_step(
    x: np.ndarray,
    y: np.ndarray,
    heading: np.ndarray,
    speed: np.ndarray,
    accel: np.ndarray,
    steer: np.ndarray,
    wheelbase: np.ndarray | float,
    dt: float,
    ref_ahead: np.ndarray | float = 0.0,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Advance the bicycle by ``dt`` with constant ``accel`` and ``steer``; exact integration.

    (x, y) is the reference point ``ref_ahead`` metres ahead of the rear axle (0: the rear axle;
    wheelbase/2: the box centre of a car with centred axles). Speed is clamped at >= 0. Returns the
    new (x, y, heading wrapped to (-pi, pi], speed).
    """
    v0 = np.maximum(speed, 0.0)
    v1 = v0 + accel * dt
    # A braking car stops partway through the step and stays stopped: move only until then.
    # (-v1 > 0 only while braking, so the divisor is then the negative acceleration itself.)
    moving_time = dt + np.maximum(-v1, 0.0) / np.minimum(accel, -_TINY)
    v1 = np.maximum(v1, 0.0)
    arc = 0.5 * (v0 + v1) * moving_time
    turn = np.tan(steer) / wheelbase * arc
    # Chord of the arc: arc * sin(turn/2) / (turn/2); the tiny offset keeps straight driving exact.
    half = 0.5 * turn
    half_safe = half + np.copysign(_TINY, half)
    chord = arc * np.sin(half_safe) / half_safe
    mid = heading + half
    new_heading = heading + turn
    c0, s0 = np.cos(heading), np.sin(heading)
    c1, s1 = np.cos(new_heading), np.sin(new_heading)
    new_x = x + chord * np.cos(mid) + ref_ahead * (c1 - c0)
    new_y = y + chord * np.sin(mid) + ref_ahead * (s1 - s0)
    return new_x, new_y, wrap_angle(new_heading), v1
