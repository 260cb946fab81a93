"""Lane paths as polylines: arc length, projection to (s, d), extrapolation, spline references.

The observation gives three paths (route, left of it, right of it) as ego-frame points with a
mask. Planners need them as continuous curves: lengths, the Frenet coordinates of points, and
references long enough for a 3 s plan.
"""

from __future__ import annotations

import numpy as np
from scipy.interpolate import CubicSpline

from agents.planners.frames import wrap


def arc_length(xy: np.ndarray) -> np.ndarray:
    """Cumulative arc length [n] of a polyline [n, 2] (0 at the first point)."""
    xy = np.asarray(xy, dtype=np.float64)
    if len(xy) == 0:
        return np.zeros(0)
    return np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(xy, axis=0), axis=1))])


def valid_path(points: np.ndarray, mask: np.ndarray) -> np.ndarray:
    """The leading valid points [m, 3] (x, y, heading) of one observed path."""
    mask = np.asarray(mask) > 0
    m = int(np.argmin(mask)) if not mask.all() else len(mask)
    return np.asarray(points[:m], dtype=np.float64)


def extend(points: np.ndarray, count: int, spacing: float = 1.0) -> np.ndarray:
    """A path [n, 3] (x, y, heading) extended to at least ``count`` points by straight steps of
    ``spacing`` metres along its last heading (the original planners extrapolate the same way)."""
    points = np.asarray(points, dtype=np.float64)
    if len(points) >= count or len(points) == 0:
        return points
    last = points[-1]
    k = np.arange(1, count - len(points) + 1) * spacing
    extra = np.stack([last[0] + k * np.cos(last[2]), last[1] + k * np.sin(last[2]), np.full_like(k, last[2])], axis=1)
    return np.vstack([points, extra])


def project(path_xy: np.ndarray, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Frenet coordinates (s, d) [P] of points [P, 2] on a polyline [n, 2]: s along it (measured from
    its first point, extended linearly before and after its ends), d to the left of it."""
    path_xy = np.asarray(path_xy, dtype=np.float64)
    points = np.asarray(points, dtype=np.float64).reshape(-1, 2)
    if len(path_xy) < 2:
        raise ValueError(f"project: a path needs at least 2 points, got {len(path_xy)}")
    a, b = path_xy[:-1], path_xy[1:]
    seg = b - a
    seg_len = np.maximum(np.linalg.norm(seg, axis=1), 1e-9)
    rel = points[:, None, :] - a[None]
    u = np.einsum("psk,sk->ps", rel, seg) / seg_len**2
    first, last = np.zeros_like(u, dtype=bool), np.zeros_like(u, dtype=bool)
    first[:, 0], last[:, -1] = True, True
    uc = np.clip(u, np.where(first, -np.inf, 0.0), np.where(last, np.inf, 1.0))
    foot = a[None] + uc[..., None] * seg[None]
    dist = np.linalg.norm(points[:, None, :] - foot, axis=2)
    k = dist.argmin(axis=1)
    idx = np.arange(len(points))
    s0 = arc_length(path_xy)[:-1]
    s = s0[k] + uc[idx, k] * seg_len[k]
    cross = seg[k, 0] * rel[idx, k, 1] - seg[k, 1] * rel[idx, k, 0]
    return s, np.sign(cross) * dist[idx, k]


def smoothed(points: np.ndarray, sigma: float) -> np.ndarray:
    """Points [n, >=2] with x, y smoothed by a Gaussian of ``sigma`` points (ends held): lane
    polylines through junctions have kinks that a spline through every point keeps."""
    from scipy.ndimage import gaussian_filter1d

    out = np.array(points, dtype=np.float64, copy=True)
    out[:, :2] = gaussian_filter1d(points[:, :2], sigma, axis=0, mode="nearest")
    out[0, :2] = points[0, :2]
    return out


class Reference:
    """A natural cubic spline x(s), y(s) over a path's chord length, sampled every ``step`` m
    (``smooth``: Gaussian smoothing of the points first, in points)."""

    def __init__(self, points: np.ndarray, step: float = 0.1, smooth: float = 0.0):
        points = np.asarray(points, dtype=np.float64)
        if smooth > 0 and len(points) > 3:
            points = smoothed(points, smooth)
        s = arc_length(points[:, :2])
        keep = np.concatenate([[True], np.diff(s) > 1e-6])
        points, s = points[keep], s[keep]
        if len(points) < 2:
            raise ValueError("Reference: a path needs at least 2 distinct points")
        spline = CubicSpline(s, points[:, :2], bc_type="natural")
        self.s = np.arange(0.0, s[-1], step)
        self.xy = spline(self.s)
        d = spline(self.s, 1)
        self.yaw = np.arctan2(d[:, 1], d[:, 0])
        dd = spline(self.s, 2)
        self.curvature = (d[:, 0] * dd[:, 1] - d[:, 1] * dd[:, 0]) / np.maximum(np.hypot(d[:, 0], d[:, 1]) ** 3, 1e-9)
        self.length = float(s[-1])
        self.step = step

    def frenet_to_xy(self, s: np.ndarray, d: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Cartesian points [T, 2] and yaw [T] at arc lengths s (interpolated between samples) offset
        d to the left; ``valid`` where s stays on the reference (the caller truncates there)."""
        s = np.asarray(s, dtype=np.float64)
        valid = (s >= 0.0) & (s <= self.s[-1])
        x = np.interp(s, self.s, self.xy[:, 0])
        y = np.interp(s, self.s, self.xy[:, 1])
        yaw = np.interp(s, self.s, np.unwrap(self.yaw))
        normal = np.stack([-np.sin(yaw), np.cos(yaw)], axis=1)
        return np.stack([x, y], axis=1) + np.asarray(d, dtype=np.float64)[:, None] * normal, wrap(yaw), valid


def heading_of(xy: np.ndarray, fallback: float = 0.0) -> np.ndarray:
    """Headings [T] from successive points (the last repeated)."""
    xy = np.asarray(xy, dtype=np.float64)
    if len(xy) < 2:
        return np.full(len(xy), fallback)
    d = np.diff(xy, axis=0)
    h = np.arctan2(d[:, 1], d[:, 0])
    return np.concatenate([h, h[-1:]])


def assign_to_paths(paths: list[np.ndarray | None], points: np.ndarray, lane_width: float) -> np.ndarray:
    """Index of the path each point [P, 2] lies on (|d| < lane_width / 2, the nearest if several),
    -1 for none. ``paths`` holds polylines [n, >=2] or None for absent lanes."""
    points = np.asarray(points, dtype=np.float64).reshape(-1, 2)
    best = np.full(len(points), np.inf)
    out = np.full(len(points), -1, dtype=np.int64)
    for i, path in enumerate(paths):
        if path is None or len(path) < 2:
            continue
        s, d = project(path[:, :2], points)
        length = arc_length(path[:, :2])[-1]
        ok = (np.abs(d) < 0.5 * lane_width) & (s > -10.0) & (s < length + 10.0) & (np.abs(d) < best)
        best = np.where(ok, np.abs(d), best)
        out = np.where(ok, i, out)
    return out


__all__ = ["arc_length", "valid_path", "extend", "project", "Reference", "heading_of", "assign_to_paths", "wrap"]


def from_ego(points: np.ndarray, spacing: float = 1.0) -> np.ndarray:
    """A path [n, 3] resampled every ``spacing`` metres from the ego's projection onto it (the
    first point is the ego's foot point), as 2022 SMARTS waypoint paths started; the observed
    points sit on the route's fixed 1 m grid instead, whose phase would otherwise matter."""
    points = np.asarray(points, dtype=np.float64)
    if len(points) < 2:
        return points
    first = points[0]  # a point 2 m behind the first, for an ego not yet past it
    back = [first[0] - 2.0 * np.cos(first[2]), first[1] - 2.0 * np.sin(first[2]), first[2]]
    points = np.vstack([back, points])
    s = arc_length(points[:, :2])
    s0, _ = project(points[:, :2], np.zeros((1, 2)))
    start = float(np.clip(s0[0], 0.0, s[-1]))
    q = np.arange(start, s[-1] + 1e-9, spacing)
    heading = np.unwrap(points[:, 2])
    out = np.stack([np.interp(q, s, points[:, 0]), np.interp(q, s, points[:, 1]), np.interp(q, s, heading)], axis=1)
    out[:, 2] = wrap(out[:, 2])
    return out
