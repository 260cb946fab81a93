"""Ego frame <-> odometry frame, and chaining a planned pose list into RelativeTargetPose steps.

Observations carry no world pose. A planner that keeps anything across steps (histories, a plan)
works in an *odometry frame*: the ego pose integrated from the executed relative steps. Within the
action limits a RelativeTargetPose step is executed exactly, so dead reckoning with the applied
action is exact; otherwise the observed speed and yaw rate bound the error until the next re-plan.
"""

from __future__ import annotations

import numpy as np


def wrap(angle: np.ndarray | float) -> np.ndarray | float:
    """Angle(s) wrapped to [-pi, pi)."""
    return (np.asarray(angle) + np.pi) % (2 * np.pi) - np.pi


def rotation(heading: float) -> np.ndarray:
    """2x2 matrix rotating frame-local vectors into the frame whose x axis is at ``heading``."""
    c, s = np.cos(heading), np.sin(heading)
    return np.array([[c, -s], [s, c]])


def local_to_global(points: np.ndarray, pose: np.ndarray) -> np.ndarray:
    """Points [..., 2] given in the frame of ``pose`` (x, y, heading) -> the frame pose lives in."""
    return points @ rotation(pose[2]).T + pose[:2]


def global_to_local(points: np.ndarray, pose: np.ndarray) -> np.ndarray:
    """Points [..., 2] in the outer frame -> the frame of ``pose`` (x, y, heading)."""
    return (points - pose[:2]) @ rotation(pose[2])


def compose(pose: np.ndarray, step: np.ndarray) -> np.ndarray:
    """The pose reached from ``pose`` by a relative step (dx, dy, dheading) in its own frame."""
    xy = local_to_global(np.asarray(step[:2], dtype=np.float64), pose)
    return np.array([xy[0], xy[1], float(wrap(pose[2] + step[2]))])


def relative(pose: np.ndarray, target: np.ndarray) -> np.ndarray:
    """The relative step (dx, dy, dheading) from ``pose`` to ``target`` (both in one frame)."""
    xy = global_to_local(np.asarray(target[:2], dtype=np.float64), pose)
    return np.array([xy[0], xy[1], float(wrap(target[2] - pose[2]))])


def chain(poses: np.ndarray) -> np.ndarray:
    """Poses P1..PT [T, 3] planned in the ego frame at decision time (P0 = origin) -> the T
    RelativeTargetPose steps that visit them: step k is P_k in the frame of P_{k-1}."""
    poses = np.asarray(poses, dtype=np.float64)
    prev = np.vstack([np.zeros((1, 3)), poses[:-1]])
    d = poses[:, :2] - prev[:, :2]
    c, s = np.cos(prev[:, 2]), np.sin(prev[:, 2])
    dx = c * d[:, 0] + s * d[:, 1]
    dy = -s * d[:, 0] + c * d[:, 1]
    return np.stack([dx, dy, wrap(poses[:, 2] - prev[:, 2])], axis=1)


def unchain(steps: np.ndarray) -> np.ndarray:
    """Inverse of :func:`chain`: relative steps [T, 3] -> poses [T, 3] in the starting frame."""
    pose = np.zeros(3)
    out = []
    for step in np.asarray(steps, dtype=np.float64):
        pose = compose(pose, step)
        out.append(pose)
    return np.array(out).reshape(-1, 3)


class Odometry:
    """One agent's pose in its odometry frame (the ego frame of its first observed step)."""

    def __init__(self) -> None:
        self.pose = np.zeros(3)

    def advance(self, step: np.ndarray) -> None:
        """Integrate an executed relative step (dx, dy, dheading)."""
        self.pose = compose(self.pose, np.asarray(step, dtype=np.float64))

    def to_world(self, points: np.ndarray) -> np.ndarray:
        """Ego-frame points [..., 2] -> odometry frame."""
        return local_to_global(np.asarray(points, dtype=np.float64), self.pose)

    def to_ego(self, points: np.ndarray) -> np.ndarray:
        """Odometry-frame points [..., 2] -> current ego frame."""
        return global_to_local(np.asarray(points, dtype=np.float64), self.pose)
