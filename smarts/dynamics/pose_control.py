"""Pose action spaces: move vehicles to a requested next pose, limited to what a car can reach.

A request is limited in this order, all vectorised over the vehicles:

1. Speed. The displacement length ``d`` implies the speed ``d / dt``; it is clipped to the speeds
   reachable from the current one, ``[v0 - max_decel*dt, v0 + max_accel*dt]`` intersected with
   ``[0, max_speed]`` (a car above ``max_speed`` brakes at ``max_decel``). Without reverse a
   request with ``dx < 0`` is a stop request: it gets the lowest reachable forward speed. With
   reverse the speed is signed (negative = backwards) and bounded below by ``-max_reverse_speed``.
2. Heading. ``|dh| <= min(max_yaw_rate*dt, max_curvature*|d|)``: no turning on the spot.
3. Direction. A car without slip moves along the chord between its old and new heading, so the
   displacement direction (relative to the old heading) is clipped to ``dh/2 +- max_slip``.

The achieved speed written to the table is ``d / dt`` of the limited displacement (signed).
"""

from __future__ import annotations

import numpy as np

from smarts.core.vehicle_table import VehicleTable
from smarts.dynamics.action_spaces import ActionSpaceType, check_actions
from smarts.dynamics.limits import ReachLimits

_TWO_PI = 2.0 * np.pi
_INV_TWO_PI = 1.0 / _TWO_PI


def wrap_angle(angle):
    """Wrap angles (scalar or array) to (-pi, pi]; angles already in range come back unchanged."""
    return angle + _TWO_PI * np.floor((np.pi - angle) * _INV_TWO_PI)


def limit_relative_pose(
    dxdydh: np.ndarray, speed: np.ndarray, dt: float, limits: ReachLimits
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Limit vehicle-frame requests ``float64[n, 3]`` (dx forward, dy left, dheading) to one step.

    ``speed`` is the current signed forward speed of each vehicle. Returns the reachable
    ``(dx, dy, dh, new_speed)``; inputs must be finite (see ``check_actions``).
    """
    dx, dy, dh = dxdydh[:, 0], dxdydh[:, 1], dxdydh[:, 2]
    dist = np.hypot(dx, dy)
    backward = dx < 0.0
    if limits.allow_reverse:
        step0 = speed * dt
        # Braking is limited by max_decel, speeding up (either way) by max_accel.
        d_min = step0 - np.where(speed > 0.0, limits.max_decel, limits.max_accel) * (dt * dt)
        d_max = step0 + np.where(speed < 0.0, limits.max_decel, limits.max_accel) * (dt * dt)
        d = np.where(backward, -dist, dist)
        d = np.minimum(np.maximum(d, -limits.max_reverse_speed * dt), limits.max_speed * dt)
        # Angle of the displacement from the axis the car moves along (its rear when backward).
        direction = np.arctan2(np.where(backward, -dy, dy), np.abs(dx))
    else:
        step0 = np.maximum(speed, 0.0) * dt
        d_min = step0 - limits.max_decel * (dt * dt)
        d_max = step0 + limits.max_accel * (dt * dt)
        d = np.minimum(dist * ~backward, limits.max_speed * dt)  # backward: a stop request
        direction = np.arctan2(dy, np.abs(dx))
    # Clipping to the speed caps first and then to what accel/decel reach from the current speed
    # gives their intersection, or (above max_speed) the nearest speed the brakes can reach.
    d = np.minimum(np.maximum(d, d_min), d_max)
    d_abs = np.abs(d) if limits.allow_reverse else d

    turn = np.minimum(limits.max_curvature * d_abs, limits.max_yaw_rate * dt)
    dh_lim = np.minimum(np.maximum(dh, -turn), turn)

    chord = 0.5 * dh_lim
    direction = chord + np.minimum(np.maximum(direction - chord, -limits.max_slip), limits.max_slip)
    return d * np.cos(direction), d * np.sin(direction), dh_lim, d * (1.0 / dt)


def _checked(
    kind: ActionSpaceType, actions: np.ndarray, table: VehicleTable, rows: np.ndarray
) -> np.ndarray:
    """Cheap guard: a bad action must never reach the table; errors name the vehicles."""
    actions = np.asarray(actions, dtype=np.float64)
    if actions.shape != (len(rows), 3) or not np.isfinite(actions).all():
        check_actions(kind, actions, [str(table.ids[r]) for r in np.asarray(rows).tolist()])
    return actions


def _write_motion(
    table: VehicleTable,
    rows: np.ndarray,
    heading: np.ndarray,
    dx: np.ndarray,
    dy: np.ndarray,
    dh: np.ndarray,
    speed: np.ndarray,
    dt: float,
) -> None:
    """Move rows by a vehicle-frame displacement and write the derived kinematic columns."""
    c, s = np.cos(heading), np.sin(heading)
    table.x[rows] += c * dx - s * dy
    table.y[rows] += s * dx + c * dy
    table.heading[rows] = wrap_angle(heading + dh)
    accel = (speed - table.speed[rows]) / dt
    table.jerk[rows] = (accel - table.accel[rows]) / dt
    table.accel[rows] = accel
    table.speed[rows] = speed
    yaw_rate = dh / dt
    table.yaw_rate[rows] = yaw_rate
    table.lat_accel[rows] = speed * yaw_rate


def apply_relative_pose(
    table: VehicleTable, rows: np.ndarray, actions: np.ndarray, dt: float, limits: ReachLimits
) -> None:
    """Drive ``rows`` by RelativeTargetPose actions ``[n, 3]`` (dx, dy, dheading; vehicle frame)."""
    actions = _checked(ActionSpaceType.RELATIVE_TARGET_POSE, actions, table, rows)
    heading = table.heading[rows]
    dx, dy, dh, speed = limit_relative_pose(actions, table.speed[rows], dt, limits)
    _write_motion(table, rows, heading, dx, dy, dh, speed, dt)


def world_to_relative(
    table: VehicleTable, rows: np.ndarray, targets: np.ndarray
) -> np.ndarray:
    """World-frame target poses ``[n, 3]`` (x, y, heading) as vehicle-frame (dx, dy, dheading)."""
    heading = table.heading[rows]
    c, s = np.cos(heading), np.sin(heading)
    wx = targets[:, 0] - table.x[rows]
    wy = targets[:, 1] - table.y[rows]
    rel = np.empty((len(heading), 3))
    rel[:, 0] = c * wx + s * wy
    rel[:, 1] = c * wy - s * wx
    rel[:, 2] = wrap_angle(targets[:, 2] - heading)
    return rel


def apply_target_pose(
    table: VehicleTable, rows: np.ndarray, actions: np.ndarray, dt: float, limits: ReachLimits
) -> None:
    """Drive ``rows`` by TargetPose actions ``[n, 3]`` (x, y, heading; world frame).

    The target becomes a vehicle-frame request and is limited exactly like RelativeTargetPose.
    """
    actions = _checked(ActionSpaceType.TARGET_POSE, actions, table, rows)
    heading = table.heading[rows]
    rel = world_to_relative(table, rows, actions)
    dx, dy, dh, speed = limit_relative_pose(rel, table.speed[rows], dt, limits)
    _write_motion(table, rows, heading, dx, dy, dh, speed, dt)
