"""Per-step events, computed for all vehicles at once.

Each function takes arrays (rows of the vehicle table, map lookups) and returns boolean arrays; which
events end an episode is decided by the scenario's ``events.terminate_on`` list, not here.
"""

from __future__ import annotations

from enum import IntEnum

import numpy as np

from smarts.core.geometry import wrap_angle


class Event(IntEnum):
    COLLISION = 0
    OFF_ROAD = 1  # the box centre has left the drivable surface (the vehicle is mostly off)
    PARTIAL_OFF_ROAD = 2  # at least one box corner is off the drivable surface
    WRONG_WAY = 3  # driving against the lane direction outside junctions
    OFF_ROUTE = 4  # on a road that is not part of the mission route
    REACHED_GOAL = 5
    NOT_MOVING = 6  # moved less than a distance within a time window
    MAX_STEPS = 7  # the episode step limit is reached


EVENT_NAMES: tuple[str, ...] = tuple(e.name.lower() for e in Event)
NUM_EVENTS = len(Event)


def event_from_name(name: str) -> Event:
    try:
        return Event[name.upper()]
    except KeyError:
        raise ValueError(f"unknown event {name!r}; expected one of {list(EVENT_NAMES)}") from None


def box_collisions(corners: np.ndarray, x: np.ndarray, y: np.ndarray, radius: np.ndarray) -> np.ndarray:
    """Which of n oriented boxes overlap another box, by the separating axis test.

    ``corners`` is float64[n, 4, 2] (from ``VehicleTable.corners``), ``radius`` each box's half
    diagonal. A cheap circle test picks candidate pairs; the separating axis test on both boxes' two
    edge directions decides. Returns bool[n].
    """
    n = len(x)
    hit = np.zeros(n, dtype=bool)
    if n < 2:
        return hit
    dx = x[:, None] - x[None, :]
    dy = y[:, None] - y[None, :]
    reach = radius[:, None] + radius[None, :]
    close = dx * dx + dy * dy < reach * reach
    i, j = np.nonzero(np.triu(close, 1))
    if i.size == 0:
        return hit
    a, b = corners[i], corners[j]  # [m, 4, 2]
    # Edge directions of both boxes: 2 axes each (the other two edges are parallel).
    axes = np.concatenate([a[:, 1:3] - a[:, 0:2], b[:, 1:3] - b[:, 0:2]], axis=1)  # [m, 4, 2]
    pa = np.einsum("mkd,mad->mka", axes, a)  # projections [m, axis, corner]
    pb = np.einsum("mkd,mad->mka", axes, b)
    separated = (pa.max(axis=2) < pb.min(axis=2)) | (pb.max(axis=2) < pa.min(axis=2))
    overlap = ~separated.any(axis=1)
    hit[i[overlap]] = True
    hit[j[overlap]] = True
    return hit


def wrong_way(heading: np.ndarray, lane_heading: np.ndarray, lane: np.ndarray, lane_internal: np.ndarray) -> np.ndarray:
    """More than 90 degrees off the lane direction, ignoring junction lanes (they cross each other)."""
    diff = np.abs(wrap_angle(heading - lane_heading))
    on_normal_lane = (lane >= 0) & ~lane_internal[np.maximum(lane, 0)]
    return on_normal_lane & (diff > 0.5 * np.pi)


class NotMovingTracker:
    """Flags vehicles that stayed within ``distance`` of an anchor point for ``seconds``.

    O(1) per vehicle per step: the anchor moves to the current position whenever the vehicle gets
    farther than ``distance`` from it, and the time of that move is remembered.
    """

    def __init__(self, capacity: int, seconds: float, distance: float):
        self.seconds = seconds
        self.distance = distance
        self.anchor = np.zeros((capacity, 2))
        self.anchor_time = np.zeros(capacity)

    def reset_rows(self, rows: np.ndarray, x: np.ndarray, y: np.ndarray, time: float) -> None:
        self.anchor[rows, 0] = x
        self.anchor[rows, 1] = y
        self.anchor_time[rows] = time

    def update(self, rows: np.ndarray, x: np.ndarray, y: np.ndarray, time: float) -> np.ndarray:
        ddx = x - self.anchor[rows, 0]
        ddy = y - self.anchor[rows, 1]
        moved = ddx * ddx + ddy * ddy > self.distance * self.distance
        moved_rows = rows[moved]
        self.anchor[moved_rows, 0] = x[moved]
        self.anchor[moved_rows, 1] = y[moved]
        self.anchor_time[moved_rows] = time
        return time - self.anchor_time[rows] >= self.seconds - 1e-9
