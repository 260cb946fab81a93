"""The pose controller (``smarts.dynamics.pose_control``) as torch tensor ops, for any torch device.

The compiled kernel loops over rows; here every step of the same limiter is one tensor op over all
rows, so the stage runs on a GPU when the simulation asks for one (``--device cuda``). The vehicle
table stays a numpy array: the rows' columns go to the device, the results come back. Arithmetic
is float64 and in the kernel's order, so results agree with it to rounding of the transcendental
functions (tests/dynamics/test_pose_control_torch.py holds the two to 1e-12).
"""

from __future__ import annotations

import math
import re

import numpy as np
import torch

from smarts.core.vehicle_table import COLUMN, VehicleTable
from smarts.dynamics.action_spaces import ActionSpaceType
from smarts.dynamics.limits import ReachLimits
from smarts.dynamics.pose_control import _checked

DEVICE_CHOICES = ("cpu", "torch-cpu", "cuda", "cuda:N")
"""Where simulation stages run: ``cpu`` the compiled numpy kernels; ``torch-cpu`` the torch
stages on the CPU (for checking them); ``cuda`` / ``cuda:N`` the torch stages on that GPU."""

_CUDA = re.compile(r"cuda(:\d+)?")
_TWO_PI = 2.0 * math.pi
_INV_TWO_PI = 1.0 / _TWO_PI
_READ = np.array([COLUMN[c] for c in ("x", "y", "heading", "speed", "accel")])
_WRITE = np.array([COLUMN[c] for c in ("x", "y", "heading", "speed", "accel", "jerk", "yaw_rate", "lat_accel")])


def check_device_name(name: str) -> str:
    """``name`` if it is one of ``DEVICE_CHOICES`` (whether its GPU exists is ``resolve_device``'s
    question: a config naming ``cuda`` stays readable on a machine without one)."""
    if not isinstance(name, str) or not (name in ("cpu", "torch-cpu") or _CUDA.fullmatch(name)):
        raise ValueError(f"unknown device {name!r}; expected one of {', '.join(DEVICE_CHOICES)}")
    return name


def resolve_device(name: str) -> torch.device | None:
    """The torch device the torch stages run on, or None for the compiled numpy kernels (``cpu``).

    Raises ``ValueError`` naming ``device`` for an unknown name or a GPU that is not visible."""
    check_device_name(name)
    if name == "cpu":
        return None
    if name == "torch-cpu":
        return torch.device("cpu")
    if not torch.cuda.is_available():
        raise ValueError(
            f"device: {name!r} asks for a GPU but no CUDA GPU is visible to torch "
            "(torch.cuda.is_available() is False); use cpu or torch-cpu"
        )
    device = torch.device(name)
    count = torch.cuda.device_count()
    if device.index is not None and device.index >= count:
        raise ValueError(f"device: {name!r} names GPU {device.index} but only {count} CUDA GPU(s) are visible")
    return device


def _wrap(angle: torch.Tensor) -> torch.Tensor:
    """``smarts.core.geometry.wrap_angle`` in torch: radians to (-pi, pi]."""
    return angle + _TWO_PI * torch.floor((math.pi - angle) * _INV_TWO_PI)


def limit_relative_pose_torch(
    dx: torch.Tensor, dy: torch.Tensor, dh: torch.Tensor, v0: torch.Tensor, dt: float, limits: ReachLimits
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor]:
    """``pose_control.limit_relative_pose`` on float64 tensors of vehicle-frame requests (the
    order of the limits is the module docstring's there); returns ``(dx, dy, dh, new_speed)``."""
    dist = torch.hypot(dx, dy)
    backward = dx < 0.0
    if limits.allow_reverse:
        step0 = v0 * dt
        # Braking is limited by max_decel, speeding up (either way) by max_accel.
        # (float64 scalars: torch.where of two Python floats would give float32)
        decel, accel = v0.new_tensor(limits.max_decel), v0.new_tensor(limits.max_accel)
        d_min = step0 - torch.where(v0 > 0.0, decel, accel) * dt * dt
        d_max = step0 + torch.where(v0 < 0.0, decel, accel) * dt * dt
        d = torch.where(backward, -dist, dist)
        d = torch.clamp(d, -limits.max_reverse_speed * dt, limits.max_speed * dt)
        direction = torch.atan2(torch.where(backward, -dy, dy), torch.abs(dx))
    else:
        step0 = torch.clamp(v0, min=0.0) * dt
        d_min = step0 - limits.max_decel * dt * dt
        d_max = step0 + limits.max_accel * dt * dt
        d = torch.where(backward, 0.0, torch.clamp(dist, max=limits.max_speed * dt))  # backward: stop
        direction = torch.atan2(dy, torch.abs(dx))
    d = torch.minimum(torch.maximum(d, d_min), d_max)
    turn = torch.clamp(limits.max_curvature * torch.abs(d), max=limits.max_yaw_rate * dt)
    dh = torch.minimum(torch.maximum(dh, -turn), turn)
    chord = 0.5 * dh
    direction = chord + torch.clamp(direction - chord, -limits.max_slip, limits.max_slip)
    return d * torch.cos(direction), d * torch.sin(direction), dh, d / dt


@torch.inference_mode()  # no autograd bookkeeping: a little less overhead per op
def apply_pose_torch(
    table: VehicleTable,
    rows: np.ndarray,
    actions: np.ndarray,
    world_frame: bool,
    dt: float,
    limits: ReachLimits,
    device: torch.device,
) -> None:
    """Drive ``rows`` (distinct) by pose actions ``[n, 3]`` on ``device``: RelativeTargetPose
    (dx, dy, dheading; vehicle frame) or, with ``world_frame``, TargetPose (x, y, heading).

    Writes x, y, heading, speed, accel, jerk, yaw_rate and lat_accel of the rows in place, as
    ``apply_relative_pose`` / ``apply_target_pose`` do."""
    rows = np.asarray(rows, dtype=np.int64)
    kind = ActionSpaceType.TARGET_POSE if world_frame else ActionSpaceType.RELATIVE_TARGET_POSE
    actions = _checked(kind, actions, table, rows)
    if len(rows) == 0:
        return
    state = torch.from_numpy(table.data[_READ[:, None], rows]).to(device)  # only these rows
    req = torch.from_numpy(np.ascontiguousarray(actions.T)).to(device)
    x, y, h, v0, a0 = state
    dx, dy, dh = req
    c, s = torch.cos(h), torch.sin(h)
    if world_frame:  # a target pose: express it in the vehicle frame first
        wx, wy = dx - x, dy - y
        dx, dy = c * wx + s * wy, c * wy - s * wx
        dh = _wrap(dh - h)
    dx, dy, dh, v = limit_relative_pose_torch(dx, dy, dh, v0, dt, limits)
    accel = (v - v0) / dt
    yaw_rate = dh / dt
    out = torch.stack(
        (
            x + c * dx - s * dy,
            y + s * dx + c * dy,
            _wrap(h + dh),
            v,
            accel,
            (accel - a0) / dt,
            yaw_rate,
            v * yaw_rate,
        )
    )
    table.data[_WRITE[:, None], rows] = out.cpu().numpy()
