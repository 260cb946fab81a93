"""Lane action space controller: follow a look-ahead point at a target speed, vectorised.

The simulator owns the map: it picks each vehicle's look-ahead point on the lane it should be in
(the current lane, or the neighbour after a lane-change command) and hands the points over as an
array.
This module only turns (target speed, look-ahead point) into acceleration and steering and moves the
cars with the kinematic bicycle, within the same ``ReachLimits`` as the pose action spaces.

- Speed: proportional control ``accel = gain * (target - speed)``, the gain capped at ``1/dt`` so a
  step never overshoots, then clipped to ``[-max_decel, max_accel]``.
- Steering: pure pursuit from the rear axle, curvature ``2 * lateral / distance^2`` to the
  look-ahead point, clipped to ``max_curvature`` and to ``max_yaw_rate / speed``.
"""

from __future__ import annotations

import numpy as np

from smarts.core.geometry import wrap_angle
from smarts.core.vehicle_table import VehicleTable
from smarts.dynamics.bicycle import bicycle_step
from smarts.dynamics.limits import ReachLimits

DEFAULT_SPEED_GAIN = 2.0  # 1/s: closes half the speed gap in about a third of a second

_MIN_LOOKAHEAD_SQ = 1.0e-6
_MIN_SPEED = 1.0e-3


def lane_control_step(
    table: VehicleTable,
    rows: np.ndarray,
    target_speed: np.ndarray,
    lookahead_xy: np.ndarray,
    dt: float,
    limits: ReachLimits,
    wheelbase: np.ndarray | float,
    speed_gain: float = DEFAULT_SPEED_GAIN,
) -> None:
    """Drive ``rows`` one step toward ``lookahead_xy`` ``[n, 2]`` at ``target_speed`` ``[n]``.

    Writes x, y, heading, speed, accel, jerk, yaw_rate, lat_accel and steering of the rows in place.
    ``wheelbase`` is per vehicle (array) or shared (scalar); the table position is the box centre,
    taken to lie half a wheelbase ahead of the rear axle.
    """
    x, y, heading = table.x[rows], table.y[rows], table.heading[rows]
    v0 = table.speed[rows]
    target = np.minimum(np.maximum(target_speed, 0.0), limits.max_speed)
    gain = min(speed_gain, 1.0 / dt)
    accel = np.minimum(np.maximum(gain * (target - v0), -limits.max_decel), limits.max_accel)

    c, s = np.cos(heading), np.sin(heading)
    half_base = 0.5 * wheelbase
    wx = lookahead_xy[:, 0] - (x - half_base * c)
    wy = lookahead_xy[:, 1] - (y - half_base * s)
    lateral = c * wy - s * wx
    curvature = 2.0 * lateral / np.maximum(wx * wx + wy * wy, _MIN_LOOKAHEAD_SQ)
    fastest = np.maximum(np.maximum(v0, v0 + accel * dt), _MIN_SPEED)
    max_k = np.minimum(limits.max_yaw_rate / fastest, limits.max_curvature)
    curvature = np.minimum(np.maximum(curvature, -max_k), max_k)
    steer = np.arctan(curvature * wheelbase)

    nx, ny, nh, nv = bicycle_step(x, y, heading, v0, accel, steer, wheelbase, dt, half_base)
    table.x[rows] = nx
    table.y[rows] = ny
    table.heading[rows] = nh
    achieved = (nv - v0) / dt
    table.jerk[rows] = (achieved - table.accel[rows]) / dt
    table.accel[rows] = achieved
    table.speed[rows] = nv
    yaw_rate = wrap_angle(nh - heading) / dt
    table.yaw_rate[rows] = yaw_rate
    table.lat_accel[rows] = nv * yaw_rate
    table.steering[rows] = steer
