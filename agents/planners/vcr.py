"""VCR: a Bezier waypoint follower whose speed a collision estimate sets (the 2022 VCR entry).

Each step: choose a path (the current one, or the goal path once 10 steps in a row agree), build
one Bezier curve over the ego and the path's remaining waypoints, take its point about 1 m ahead
with the tangent heading, and move ``f`` times that step: f = 1.1 with nothing near, 2.5 when
someone is close behind, and sigma(20 (1 - p) - 14) when something is in front, p being the
collision probability (the classifier's, averaged over the last 10 steps with weights 0.6^age).
Nominal speed is therefore about 11 m/s.

``risk`` gives p: the learned event classifier over rasters (``zoo:vcr``), or a time-to-collision
surrogate p = clip((T0 - TTC) / T0, 0, 1), T0 = 3 s, over the front obstacles (``zoo:vcr-ttc``),
since the speed map needs some p (with p = 0 it drives into leaders). Deviations: the three
observed paths stand in for the lane paths; endless missions take the route path (the original
picked the path nearest the world origin); the L-shaped fallback is dropped (the goal is appended
when the path ends); histories are cleared per agent on a new episode.
"""

from __future__ import annotations

from collections import deque
from typing import Callable

import numpy as np

from agents.obs_columns import GOAL_XY, Ego, Goal, Neighbour, WaypointPath
from agents.planners.agent_state import AgentState, StatefulPlanner
from agents.planners.frames import wrap
from agents.planners.geometry import bezier_length, bezier_points, bezier_tangents
from agents.planners.paths import from_ego, valid_path

INTERFACE = {"waypoints": {"count": 20, "spacing": 1}, "neighbours": {"count": 10, "radius": 50.0}}
RASTERS = {"size": 64, "resolution": 0.8, "layers": ["drivable", "route", "occupancy"]}
"""What the learned classifier sees (64 x 64 at 0.8 m: about 51 m across)."""
LEARNED_INTERFACE = {**INTERFACE, "rasters": RASTERS}
HISTORY = 10
DECAY = 0.6
PATH_POINTS = 18
OBSTACLE_RANGE = 12.0
FRONT, REAR = np.deg2rad(60.0), np.deg2rad(120.0)
OPPOSITE = np.deg2rad(175.0)
TTC_HORIZON = 3.0
NUMBERS = 24
"""The classifier's numeric input (``classifier_numbers``)."""


def speed_factor(p_collision: float) -> float:
    """sigma(20 (1 - p) - 14): 0.9975 at p = 0, 0.5 at p = 0.3, 0.018 at p = 0.5."""
    return float(1.0 / (1.0 + np.exp(-(20.0 * (1.0 - p_collision) - 14.0))))


def obstacles(row: dict[str, np.ndarray]) -> tuple[np.ndarray, np.ndarray]:
    """(front rows, rear rows) of neighbours within 12 m: bearing within +-60 deg is front, beyond
    +-120 deg rear; road users heading the opposite way (|dheading| > 175 deg) are dropped."""
    nb = row["neighbours"].astype(np.float64)
    present = np.flatnonzero(row["neighbour_mask"] > 0)
    dist = np.hypot(nb[present, Neighbour.DX], nb[present, Neighbour.DY])
    bearing = np.abs(np.arctan2(nb[present, Neighbour.DY], nb[present, Neighbour.DX]))
    dh = np.abs(np.arctan2(nb[present, Neighbour.SIN_HEADING], nb[present, Neighbour.COS_HEADING]))
    keep = (dist < OBSTACLE_RANGE) & (dh <= OPPOSITE)
    return present[keep & (bearing <= FRONT)], present[keep & (bearing >= REAR)]


def ttc_risk(row: dict[str, np.ndarray], front: np.ndarray, plan: np.ndarray, dt: float = 0.1) -> float:
    """The rule surrogate of the collision probability of the candidate step: clip((T0 - TTC) / T0,
    0, 1), TTC being the smallest time to contact with a front obstacle if the ego drove at the
    candidate's speed (its first path point per step, as the classifier judges the candidate)
    while the obstacle keeps its velocity."""
    if front.size == 0:
        return 0.0
    nb = row["neighbours"].astype(np.float64)
    ego = row["ego"].astype(np.float64)
    bearing = np.arctan2(nb[front, Neighbour.DY], nb[front, Neighbour.DX])
    dist = np.hypot(nb[front, Neighbour.DX], nb[front, Neighbour.DY])
    gap = dist - 0.5 * (nb[front, Neighbour.LENGTH] + ego[Ego.LENGTH])
    planned = float(np.hypot(plan[0, 0], plan[0, 1])) / dt
    own = np.array([nb[front, Neighbour.VX] + ego[Ego.SPEED], nb[front, Neighbour.VY]])  # obstacle velocity, ego frame
    closing = planned * np.cos(bearing) - (own[0] * np.cos(bearing) + own[1] * np.sin(bearing))
    ttc = np.where(gap <= 0, 0.0, np.where(closing > 1e-3, gap / np.maximum(closing, 1e-3), np.inf))
    return float(np.clip((TTC_HORIZON - ttc.min()) / TTC_HORIZON, 0.0, 1.0))


def classifier_numbers(row: dict[str, np.ndarray], step: np.ndarray, path: np.ndarray) -> np.ndarray:
    """The event classifier's 24 numbers, ego frame: the step (x, y, heading) and the next 5 path
    points (VCR's 18), then what one raster frame cannot show: the ego's speed and the nearest
    neighbour ahead (within +-60 deg: present, bumper gap, lateral offset, velocity relative to
    the ego). Speeds and distances are divided by 10."""
    out = np.zeros(NUMBERS, dtype=np.float32)
    out[0:3] = step[:3]
    k = min(5, len(path) - 1)
    if k > 0:
        out[3 : 3 + 3 * k] = np.asarray(path[1 : 1 + k, :3], dtype=np.float32).reshape(-1)
    ego = row["ego"].astype(np.float64)
    out[18] = ego[Ego.SPEED] / 10.0
    nb = row["neighbours"].astype(np.float64)
    present = np.flatnonzero(row["neighbour_mask"] > 0)
    dx, dy = nb[present, Neighbour.DX], nb[present, Neighbour.DY]
    ahead = present[(dx > 0) & (np.abs(np.arctan2(dy, dx)) <= FRONT)]
    if ahead.size:
        i = ahead[np.argmin(np.hypot(nb[ahead, Neighbour.DX], nb[ahead, Neighbour.DY]))]
        gap = float(nb[i, Neighbour.DX]) - 0.5 * (float(nb[i, Neighbour.LENGTH]) + float(ego[Ego.LENGTH]))
        side, vx, vy = nb[i, Neighbour.DY], nb[i, Neighbour.VX], nb[i, Neighbour.VY]
        out[19:24] = [1.0, gap / 10.0, side / 10.0, vx / 10.0, vy / 10.0]
    return out


class VCRState(AgentState):
    def __init__(self) -> None:
        super().__init__()
        self.goal_paths: deque[int] = deque(maxlen=HISTORY)
        self.scores: deque[float] = deque(maxlen=HISTORY)
        self.path = -1
        self.factor = 1.1
        self.p_collision = 0.0


class VCRPlanner(StatefulPlanner):
    """VCR's follower; ``risk(row, front_rows, plan) -> p_collision`` (default: the TTC rule)."""

    interface = INTERFACE

    def __init__(self, risk: Callable[..., float] | None = None, interface: dict | None = None):
        super().__init__()
        self.risk = risk or ttc_risk
        if interface is not None:
            self.interface = interface

    def new_state(self) -> VCRState:
        return VCRState()

    def choose_path(self, st: VCRState, row: dict[str, np.ndarray]) -> np.ndarray | None:
        wp, mask, goal = row["waypoints"], row["waypoint_mask"], row["goal"]
        paths = {p: from_ego(valid_path(wp[p], mask[p])) for p in range(wp.shape[0])}
        paths = {p: pts for p, pts in paths.items() if len(pts) >= 1}
        if not paths:
            return None
        current = min(paths, key=lambda p: float(np.hypot(*paths[p][0, :2])))
        if goal[Goal.HAS_GOAL] > 0:
            target = min(paths, key=lambda p: float(np.hypot(*(paths[p][-1, :2] - goal[GOAL_XY]))))
        else:
            target = WaypointPath.ROUTE if WaypointPath.ROUTE in paths else current
        st.goal_paths.append(target)
        if st.path not in paths:
            st.path = current
        if len(st.goal_paths) == HISTORY and len(set(st.goal_paths)) == 1 and target != current:
            st.path = target
        else:
            st.path = current
        return paths[st.path]

    def plan(self, st: VCRState, row: dict[str, np.ndarray]) -> np.ndarray | None:
        """18 points (x, y, heading) along the Bezier curve over the ego and the path ahead."""
        pts = self.choose_path(st, row)
        if pts is None:
            return None
        start = len(pts) - 1
        for i, (x, y, h) in enumerate(pts):
            bearing_ok = abs(np.arctan2(y, x)) <= np.deg2rad(35.0)
            left_of_line = x * np.sin(h) - y * np.cos(h) > 0.5
            if bearing_ok and (left_of_line or np.hypot(x, y) > 0.2):
                start = i
                break
        control = np.vstack([np.zeros(2), pts[start:, :2]])
        goal = row["goal"]
        if len(pts) - start <= 1 and goal[Goal.HAS_GOAL] > 0:
            control = np.vstack([control, goal[None, GOAL_XY]])
        if len(control) < 2:
            return None
        length = bezier_length(control)
        t = np.minimum(np.arange(1, PATH_POINTS + 1) / max(length, 1e-6), 1.0)
        xy = bezier_points(control, t)
        tangent = bezier_tangents(control, t)
        return np.column_stack([xy, np.arctan2(tangent[:, 1], tangent[:, 0])])

    def decide(self, st: VCRState, row: dict[str, np.ndarray]) -> np.ndarray:
        try:
            path = self.plan(st, row)
        except (ValueError, np.linalg.LinAlgError, FloatingPointError):
            path = None
        if path is None:  # the original's reaction to any failure: stay (brake)
            return np.zeros(3)
        front, rear = obstacles(row)
        if front.size:
            st.scores.append(float(self.risk(row, front, path)))
            w = DECAY ** np.arange(len(st.scores) - 1, -1, -1)
            st.p_collision = float(np.dot(w, np.array(st.scores)) / w.sum())
            st.factor = speed_factor(st.p_collision)
        elif rear.size:
            near = np.hypot(row["neighbours"][rear, Neighbour.DX], row["neighbours"][rear, Neighbour.DY]).min() < 5.0
            st.factor = 2.5 if near else 1.1
        else:
            st.factor = 1.1
        p1 = path[0]
        return np.array([st.factor * p1[0], st.factor * p1[1], float(wrap(p1[2]))])
