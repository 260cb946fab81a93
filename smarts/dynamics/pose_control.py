"""Pose action spaces: move vehicles to a requested next pose, limited to what a car can reach.

A request is limited in this order:

All of it runs in one compiled loop over the vehicles (see ``_limit_one``).

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

import math

import numpy as np

from smarts.compiled import njit
from smarts.core.geometry import wrap_scalar
from smarts.core.vehicle_table import COLUMN, VehicleTable
from smarts.dynamics.action_spaces import ActionSpaceType, check_actions
from smarts.dynamics.limits import ReachLimits


def limit_relative_pose(
    dxdydh: np.ndarray, speed: np.ndarray, dt: float, limits: ReachLimits
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Limit vehicle-frame requests ``float64[n, 3]`` (dx forward, dy left, dheading) to one step.

    ``speed`` is the current signed forward speed of each vehicle. Returns the reachable
    ``(dx, dy, dh, new_speed)``; inputs must be finite (see ``check_actions``).
    """
    req = np.ascontiguousarray(dxdydh, dtype=np.float64)
    out = np.empty((len(req), 4))
    _limit_kernel(req, np.ascontiguousarray(speed, dtype=np.float64), dt, limit_params(limits), out)
    return out[:, 0], out[:, 1], out[:, 2], out[:, 3]


def limit_params(limits: ReachLimits) -> np.ndarray:
    """The limits as the pose kernels read them: float64[8]."""
    return np.array(
        [
            limits.max_speed,
            limits.max_accel,
            limits.max_decel,
            limits.max_yaw_rate,
            limits.max_curvature,
            limits.max_slip,
            1.0 if limits.allow_reverse else 0.0,
            limits.max_reverse_speed,
        ]
    )


@njit(nogil=True)
def _limit_one(dx, dy, dh, v0, dt, params):  # pragma: no cover - compiled
    """The limiter for one request; see the module docstring for the order of the limits."""
    max_speed, max_accel, max_decel, max_yaw_rate, max_curvature, max_slip = params[:6]
    allow_reverse, max_reverse_speed = params[6] > 0.0, params[7]
    dist = math.hypot(dx, dy)
    backward = dx < 0.0
    if allow_reverse:
        step0 = v0 * dt
        # Braking is limited by max_decel, speeding up (either way) by max_accel.
        d_min = step0 - (max_decel if v0 > 0.0 else max_accel) * dt * dt
        d_max = step0 + (max_decel if v0 < 0.0 else max_accel) * dt * dt
        d = -dist if backward else dist
        d = min(max(d, -max_reverse_speed * dt), max_speed * dt)
        # Angle of the displacement from the axis the car moves along (its rear when backward).
        direction = math.atan2(-dy if backward else dy, abs(dx))
    else:
        step0 = max(v0, 0.0) * dt
        d_min = step0 - max_decel * dt * dt
        d_max = step0 + max_accel * dt * dt
        d = 0.0 if backward else min(dist, max_speed * dt)  # backward: a stop request
        direction = math.atan2(dy, abs(dx))
    # Clipping to the speed caps first and then to what accel/decel reach from the current speed
    # gives their intersection, or (above max_speed) the nearest speed the brakes can reach.
    d = min(max(d, d_min), d_max)
    turn = min(max_curvature * abs(d), max_yaw_rate * dt)
    dh = min(max(dh, -turn), turn)
    chord = 0.5 * dh
    direction = chord + min(max(direction - chord, -max_slip), max_slip)
    return d * math.cos(direction), d * math.sin(direction), dh, d / dt


@njit(nogil=True)
def _limit_kernel(req, speed, dt, params, out):  # pragma: no cover - compiled
    for i in range(req.shape[0]):
        out[i, 0], out[i, 1], out[i, 2], out[i, 3] = _limit_one(req[i, 0], req[i, 1], req[i, 2], speed[i], dt, params)


@njit(nogil=True)
def _move_kernel(data, rows, req, world_frame, dt, params):  # pragma: no cover - compiled
    """Limit each row's request and write its new pose and derived kinematic columns."""
    for i in range(rows.shape[0]):
        r = rows[i]
        x, y, h = data[_X, r], data[_Y, r], data[_H, r]
        c, s = math.cos(h), math.sin(h)
        dx, dy, dh = req[i, 0], req[i, 1], req[i, 2]
        if world_frame:  # a target pose: express it in the vehicle frame first
            wx, wy = dx - x, dy - y
            dx, dy = c * wx + s * wy, c * wy - s * wx
            dh = wrap_scalar(dh - h)
        dx, dy, dh, v = _limit_one(dx, dy, dh, data[_SPEED, r], dt, params)
        accel = (v - data[_SPEED, r]) / dt
        yaw_rate = dh / dt
        data[_X, r] = x + c * dx - s * dy
        data[_Y, r] = y + s * dx + c * dy
        data[_H, r] = wrap_scalar(h + dh)
        data[_JERK, r] = (accel - data[_ACCEL, r]) / dt
        data[_ACCEL, r] = accel
        data[_SPEED, r] = v
        data[_YAW_RATE, r] = yaw_rate
        data[_LAT_ACCEL, r] = v * yaw_rate


_X, _Y, _H = COLUMN["x"], COLUMN["y"], COLUMN["heading"]
_SPEED, _ACCEL, _JERK = COLUMN["speed"], COLUMN["accel"], COLUMN["jerk"]
_YAW_RATE, _LAT_ACCEL = COLUMN["yaw_rate"], COLUMN["lat_accel"]


def _checked(kind: ActionSpaceType, actions: np.ndarray, table: VehicleTable, rows: np.ndarray) -> np.ndarray:
    """Cheap guard: a bad action must never reach the table; errors name the vehicles."""
    actions = np.asarray(actions, dtype=np.float64)
    if actions.shape != (len(rows), 3) or not np.isfinite(actions).all():
        check_actions(kind, actions, [str(table.ids[r]) for r in np.asarray(rows).tolist()])
    return actions


def apply_relative_pose(
    table: VehicleTable, rows: np.ndarray, actions: np.ndarray, dt: float, limits: ReachLimits
) -> None:
    """Drive ``rows`` by RelativeTargetPose actions ``[n, 3]`` (dx, dy, dheading; vehicle frame).

    Writes x, y, heading, speed, accel, jerk, yaw_rate and lat_accel of the rows in place.
    """
    actions = _checked(ActionSpaceType.RELATIVE_TARGET_POSE, actions, table, rows)
    _move_kernel(table.data, np.asarray(rows, dtype=np.int64), actions, False, dt, limit_params(limits))


def apply_target_pose(
    table: VehicleTable, rows: np.ndarray, actions: np.ndarray, dt: float, limits: ReachLimits
) -> None:
    """Drive ``rows`` by TargetPose actions ``[n, 3]`` (x, y, heading; world frame).

    The target becomes a vehicle-frame request and is limited exactly like RelativeTargetPose.
    """
    actions = _checked(ActionSpaceType.TARGET_POSE, actions, table, rows)
    _move_kernel(table.data, np.asarray(rows, dtype=np.int64), actions, True, dt, limit_params(limits))


def move_to_poses(
    table: VehicleTable, rows: np.ndarray, actions: np.ndarray, world_frame: bool, dt: float, params: np.ndarray
) -> None:
    """``apply_target_pose`` (``world_frame``) or ``apply_relative_pose`` of actions already
    checked: float64 ``[len(rows), 3]``, every number finite (the agent provider's stacked
    actions); int64 ``rows``; ``params``: ``limit_params`` of the limits, made once."""
    _move_kernel(table.data, rows, actions, world_frame, dt, params)


@njit(nogil=True)
def all_finite(values):  # pragma: no cover - compiled
    """Whether every number of a 2-D float64 array is finite (one compiled pass: a fraction of
    ``np.isfinite(values).all()``'s cost on the few numbers of a step's actions)."""
    for i in range(values.shape[0]):
        for j in range(values.shape[1]):
            if not math.isfinite(values[i, j]):
                return False
    return True
