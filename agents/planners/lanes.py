"""The observed lane paths seen from the ego: which one it is on, which are left and right of it."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from agents.planners.paths import assign_to_paths, project, valid_path


@dataclass
class LaneView:
    """Valid paths (index -> points [m, 3]), their lateral offsets from the ego (+ left) and the
    current / left / right path indices (-1 where there is none)."""

    paths: dict[int, np.ndarray]
    offset: dict[int, float]
    current: int
    left: int
    right: int

    def side(self, path: int) -> int:
        """+1 when ``path`` lies left of the current path, -1 right, 0 the same."""
        if path == self.current or path not in self.offset or self.current < 0:
            return 0
        return 1 if self.offset[path] > self.offset[self.current] else -1

    def lane_of(self, points: np.ndarray, lane_width: float) -> np.ndarray:
        """Path index of each point [P, 2] (-1: on none of the observed paths)."""
        ordered = [self.paths.get(i) for i in range(3)]
        return assign_to_paths(ordered, points, lane_width)


def lane_view(waypoints: np.ndarray, mask: np.ndarray, lane_width: float, min_points: int = 2) -> LaneView:
    """The paths of one observation, ordered by where they lie across the road."""
    paths, offset = {}, {}
    for p in range(waypoints.shape[0]):
        pts = valid_path(waypoints[p], mask[p])
        if len(pts) < min_points:
            continue
        _, d = project(pts[:, :2], np.zeros((1, 2)))
        paths[p], offset[p] = pts, -float(d[0])
    if not paths:
        return LaneView({}, {}, -1, -1, -1)
    current = min(offset, key=lambda p: abs(offset[p]))
    gap = 0.5 * max(lane_width, 2.0)
    lefts = [p for p in offset if offset[p] > offset[current] + gap]
    rights = [p for p in offset if offset[p] < offset[current] - gap]
    left = min(lefts, key=lambda p: offset[p]) if lefts else -1
    right = max(rights, key=lambda p: offset[p]) if rights else -1
    return LaneView(paths, offset, current, left, right)
