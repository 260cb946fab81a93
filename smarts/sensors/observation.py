"""The basic observation, built for every agent in one batched pass.

Everything is expressed in the ego frame (x forward, y left, headings relative to the ego's), so a
policy is invariant to where on the map it drives. Shapes are fixed; masks mark padding.

Per agent:
- ``ego`` float32[12]: speed (m/s), longitudinal acceleration (m/s^2), longitudinal jerk (m/s^3),
  lateral acceleration (m/s^2), yaw rate (rad/s), steering (rad), heading error to the lane (rad),
  lateral offset from the lane centre (m, + left), lane width (m), lane speed limit (m/s), vehicle
  length (m), vehicle width (m).
- ``neighbours`` float32[K, 8]: the K nearest vehicles within ``neighbour_radius``: dx, dy (m),
  cos and sin of the relative heading, relative velocity vx, vy (m/s, ego frame), length, width (m).
- ``neighbour_mask`` float32[K]: 1 where a neighbour is present.
- ``waypoints`` float32[3, W, 3]: paths along the route (0), the lane left of it (1) and right of it
  (2), W points ``waypoint_spacing`` route points apart: x, y (m), relative heading (rad).
- ``waypoint_mask`` float32[3, W].
- ``goal`` float32[4]: goal dx, dy (m), route distance left (m), 1 if the mission has a goal.
- ``events`` float32[8]: the events of ``smarts.core.events.Event`` this step, 0/1.
"""

from __future__ import annotations

from dataclasses import dataclass

import gymnasium as gym
import numpy as np

from smarts.core.events import NUM_EVENTS
from smarts.core.geometry import wrap_angle
from smarts.core.missions import GOAL_NONE
from smarts.core.simulation import Simulation

EGO_FEATURES = 12
NEIGHBOUR_FEATURES = 8
GOAL_FEATURES = 4
NUM_PATHS = 3


@dataclass(frozen=True)
class ObservationConfig:
    neighbours: int = 8
    neighbour_radius: float = 50.0
    waypoints: int = 20
    waypoint_spacing: int = 2  # route points are ~1 m apart, so the default looks 40 m ahead

    def __post_init__(self) -> None:
        for name in ("neighbours", "waypoints", "waypoint_spacing"):
            value = getattr(self, name)
            if not isinstance(value, int) or value < 1:
                raise ValueError(f"observation.{name}: expected a positive integer, got {value!r}")
        if not self.neighbour_radius > 0:
            raise ValueError(
                f"observation.neighbour_radius: expected a positive number, got {self.neighbour_radius!r}"
            )


def observation_space(config: ObservationConfig) -> gym.spaces.Dict:
    def box(shape, low=-np.inf, high=np.inf):
        return gym.spaces.Box(low=low, high=high, shape=shape, dtype=np.float32)

    k, w = config.neighbours, config.waypoints
    return gym.spaces.Dict(
        {
            "ego": box((EGO_FEATURES,)),
            "neighbours": box((k, NEIGHBOUR_FEATURES)),
            "neighbour_mask": box((k,), 0.0, 1.0),
            "waypoints": box((NUM_PATHS, w, 3)),
            "waypoint_mask": box((NUM_PATHS, w), 0.0, 1.0),
            "goal": box((GOAL_FEATURES,)),
            "events": box((NUM_EVENTS,), 0.0, 1.0),
        }
    )


class ObservationBuilder:
    """Builds ``{key: float32[A, ...]}`` for the agents given, all at once."""

    def __init__(self, config: ObservationConfig | None = None):
        self.config = config or ObservationConfig()
        self.space = observation_space(self.config)
        self._offsets = np.arange(self.config.waypoints) * self.config.waypoint_spacing

    def build(self, sim: Simulation, agents: np.ndarray) -> dict[str, np.ndarray]:
        cfg = self.config
        t = sim.table
        rm = sim.road_map
        n = len(agents)
        rows = sim.agent_row[agents]
        x, y, h = t.x[rows], t.y[rows], t.heading[rows]
        c, s = np.cos(h), np.sin(h)

        ego = np.empty((n, EGO_FEATURES), dtype=np.float32)
        lane = np.maximum(t.lane[rows], 0)
        ego[:, 0] = t.speed[rows]
        ego[:, 1] = t.accel[rows]
        ego[:, 2] = t.jerk[rows]
        ego[:, 3] = t.lat_accel[rows]
        ego[:, 4] = t.yaw_rate[rows]
        ego[:, 5] = t.steering[rows]
        ego[:, 6] = wrap_angle(h - t.lane_heading[rows])
        ego[:, 7] = t.t[rows]
        ego[:, 8] = rm.lane_width[lane]
        ego[:, 9] = rm.lane_speed_limit[lane]
        ego[:, 10] = t.length[rows]
        ego[:, 11] = t.width[rows]

        neighbours, neighbour_mask = self._neighbours(sim, rows, x, y, h, c, s)

        ma = sim.mission_arrays
        idx = np.minimum(sim.route_index[agents, None] + self._offsets, ma.path_len[agents, None] - 1)
        in_range = sim.route_index[agents, None] + self._offsets < ma.path_len[agents, None]
        pts = ma.paths[agents[:, None, None], np.arange(NUM_PATHS)[None, :, None], idx[:, None, :]]
        dx = pts[..., 0] - x[:, None, None]
        dy = pts[..., 1] - y[:, None, None]
        cc, ss = c[:, None, None], s[:, None, None]
        waypoints = np.empty((n, NUM_PATHS, cfg.waypoints, 3), dtype=np.float32)
        waypoints[..., 0] = cc * dx + ss * dy
        waypoints[..., 1] = -ss * dx + cc * dy
        waypoints[..., 2] = wrap_angle(pts[..., 2] - h[:, None, None])
        valid = ma.path_valid[agents[:, None, None], np.arange(NUM_PATHS)[None, :, None], idx[:, None, :]]
        waypoint_mask = (valid & in_range[:, None, :]).astype(np.float32)
        waypoints *= waypoint_mask[..., None]

        goal = np.zeros((n, GOAL_FEATURES), dtype=np.float32)
        has_goal = ma.goal_kind[agents] != GOAL_NONE
        gdx = ma.goal_xy[agents, 0] - x
        gdy = ma.goal_xy[agents, 1] - y
        goal[:, 0] = np.where(has_goal, c * gdx + s * gdy, 0.0)
        goal[:, 1] = np.where(has_goal, -s * gdx + c * gdy, 0.0)
        goal[:, 2] = ma.route_length[agents] - sim.route_progress[agents]
        goal[:, 3] = has_goal

        return {
            "ego": ego,
            "neighbours": neighbours,
            "neighbour_mask": neighbour_mask,
            "waypoints": waypoints,
            "waypoint_mask": waypoint_mask,
            "goal": goal,
            "events": sim.agent_events[agents].astype(np.float32),
        }

    def _neighbours(self, sim, rows, x, y, h, c, s):
        cfg = self.config
        t = sim.table
        n, k = len(rows), cfg.neighbours
        out = np.zeros((n, k, NEIGHBOUR_FEATURES), dtype=np.float32)
        mask = np.zeros((n, k), dtype=np.float32)
        others = t.alive_rows
        if others.size <= 1:
            return out, mask
        dx = t.x[others][None, :] - x[:, None]
        dy = t.y[others][None, :] - y[:, None]
        d2 = dx * dx + dy * dy
        d2[others[None, :] == rows[:, None]] = np.inf
        d2[d2 > cfg.neighbour_radius**2] = np.inf
        m = min(k, others.size - 1)
        if others.size - 1 > m:
            nearest = np.argpartition(d2, m - 1, axis=1)[:, :m]
        else:
            nearest = np.broadcast_to(np.arange(others.size), (n, others.size))
        order = np.take_along_axis(d2, nearest, axis=1).argsort(axis=1, kind="stable")
        nearest = np.take_along_axis(nearest, order, axis=1)[:, :m]
        present = np.isfinite(np.take_along_axis(d2, nearest, axis=1))
        nrow = others[nearest]
        ndx = np.take_along_axis(dx, nearest, axis=1)
        ndy = np.take_along_axis(dy, nearest, axis=1)
        cc, ss = c[:, None], s[:, None]
        rel_h = t.heading[nrow] - h[:, None]
        nv = t.speed[nrow]
        vx = nv * np.cos(t.heading[nrow]) - (t.speed[rows] * c)[:, None]
        vy = nv * np.sin(t.heading[nrow]) - (t.speed[rows] * s)[:, None]
        feats = out[:, :m]
        feats[..., 0] = cc * ndx + ss * ndy
        feats[..., 1] = -ss * ndx + cc * ndy
        feats[..., 2] = np.cos(rel_h)
        feats[..., 3] = np.sin(rel_h)
        feats[..., 4] = cc * vx + ss * vy
        feats[..., 5] = -ss * vx + cc * vy
        feats[..., 6] = t.length[nrow]
        feats[..., 7] = t.width[nrow]
        feats *= present[..., None]
        mask[:, :m] = present
        return out, mask
