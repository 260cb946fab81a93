"""The basic observation, built for every agent in one batched pass.

Everything is expressed in the ego frame (x forward, y left, headings relative to the ego's), so a
policy is invariant to where on the map it drives. Shapes are fixed; masks mark padding.

Per agent:
- ``ego`` float32[12]: speed (m/s), longitudinal acceleration (m/s^2), longitudinal jerk (m/s^3),
  lateral acceleration (m/s^2), yaw rate (rad/s), steering (rad), heading error to the lane (rad),
  lateral offset from the lane centre (m, + left), lane width (m), lane speed limit (m/s), vehicle
  length (m), vehicle width (m).
- ``neighbours`` float32[K, 9]: the K nearest road users within ``neighbour_radius``: dx, dy (m),
  cos and sin of the relative heading, relative velocity vx, vy (m/s, ego frame), length, width
  (m), 1 for a pedestrian (0 for a vehicle).
- ``neighbour_mask`` float32[K]: 1 where a neighbour is present.
- ``waypoints`` float32[3, W, 3]: paths along the route (0), the lane left of it (1) and right of it
  (2), W points ``waypoint_spacing`` route points apart: x, y (m), relative heading (rad).
- ``waypoint_mask`` float32[3, W].
- ``goal`` float32[4]: goal dx, dy (m), route distance left (m), 1 if the mission has a goal.
- ``signal`` float32[4]: the next traffic signal on the route: red, yellow, green (one of them 1,
  all 0 when there is none ahead) and the route distance to its stop line (m, 0 when none).
- ``events`` float32[8]: the events of ``smarts.core.events.Event`` this step, 0/1.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import gymnasium as gym
import numba
import numpy as np

from smarts.core.events import NUM_EVENTS
from smarts.core.geometry import wrap_scalar
from smarts.core.simulation import Simulation
from smarts.core.vehicle_table import COLUMN, Role

EGO_FEATURES = 12
NEIGHBOUR_FEATURES = 9
GOAL_FEATURES = 4
SIGNAL_FEATURES = 4
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
            "signal": box((SIGNAL_FEATURES,)),
            "events": box((NUM_EVENTS,), 0.0, 1.0),
        }
    )


class ObservationBuilder:
    """Builds ``{key: float32[A, ...]}`` for the agents given, all at once."""

    def __init__(self, config: ObservationConfig | None = None):
        self.config = config or ObservationConfig()
        self.space = observation_space(self.config)
        self._offsets = np.arange(self.config.waypoints) * self.config.waypoint_spacing
        self._lane_info_map = None
        self._lane_info_cache = np.zeros((0, 2))

    def build(self, sim: Simulation, agents: np.ndarray) -> dict[str, np.ndarray]:
        cfg = self.config
        ma = sim.mission_arrays
        n, k, w = len(agents), cfg.neighbours, cfg.waypoints
        obs = {
            "ego": np.empty((n, EGO_FEATURES), dtype=np.float32),
            "neighbours": np.empty((n, k, NEIGHBOUR_FEATURES), dtype=np.float32),
            "neighbour_mask": np.empty((n, k), dtype=np.float32),
            "waypoints": np.empty((n, NUM_PATHS, w, 3), dtype=np.float32),
            "waypoint_mask": np.empty((n, NUM_PATHS, w), dtype=np.float32),
            "goal": np.empty((n, GOAL_FEATURES), dtype=np.float32),
            "signal": np.empty((n, SIGNAL_FEATURES), dtype=np.float32),
            "events": np.empty((n, NUM_EVENTS), dtype=np.float32),
        }
        signals = getattr(sim, "signals", None)
        via_colour = signals.via_colour if signals is not None else self._no_signals(sim.road_map)
        _observe(
            sim.table.data, sim.table.lane, sim.table.role, sim.alive, agents, sim.agent_row[agents],
            self._lane_info(sim.road_map), ma.flat_paths, ma.flat_valid, ma.stride,
            sim.route_index, self._offsets, ma.goal_kind, ma.goal_xy, ma.route_length,
            sim.route_progress, ma.signal_via, ma.signal_s, via_colour, sim.agent_events,
            cfg.neighbour_radius**2, *obs.values(),
        )
        return obs

    def _no_signals(self, rm) -> np.ndarray:
        if getattr(self, "_no_signal_colours", None) is None or len(self._no_signal_colours) != rm.num_lanes:
            self._no_signal_colours = np.zeros(rm.num_lanes, dtype=np.int8)
        return self._no_signal_colours

    def _lane_info(self, rm) -> np.ndarray:
        """(width, speed limit) per lane, stacked once per map."""
        if self._lane_info_map is not rm:
            self._lane_info_cache = np.stack([rm.lane_width, rm.lane_speed_limit], axis=1)
            self._lane_info_map = rm
        return self._lane_info_cache


@numba.njit(cache=True, nogil=True)
def _observe(
    data, lane, role, alive, agents, rows, lane_info, flat_paths, flat_valid, stride, route_index,
    offsets, goal_kind, goal_xy, route_length, route_progress, signal_via, signal_s, via_colour,
    events, radius2,
    ego, neighbours, neighbour_mask, waypoints, waypoint_mask, goal, signal, events_out,
):  # pragma: no cover - compiled
    k_max = neighbours.shape[1]
    near_d2 = np.empty(k_max)
    near_row = np.empty(k_max, dtype=np.int64)
    for i in range(agents.shape[0]):
        a, r = agents[i], rows[i]
        x, y, h = data[_X, r], data[_Y, r], data[_H, r]
        c, s = math.cos(h), math.sin(h)
        speed = data[_SPEED, r]

        ego[i, 0] = speed
        ego[i, 1] = data[_ACCEL, r]
        ego[i, 2] = data[_JERK, r]
        ego[i, 3] = data[_LAT_ACCEL, r]
        ego[i, 4] = data[_YAW_RATE, r]
        ego[i, 5] = data[_STEERING, r]
        ego[i, 6] = wrap_scalar(h - data[_LANE_HEADING, r])
        ego[i, 7] = data[_T, r]
        ln = lane[r]
        ego[i, 8] = lane_info[ln, 0] if ln >= 0 else 0.0
        ego[i, 9] = lane_info[ln, 1] if ln >= 0 else 0.0
        ego[i, 10] = data[_LENGTH, r]
        ego[i, 11] = data[_WIDTH, r]

        # K nearest by insertion into a sorted list (K is small); equal distances keep row order.
        m = 0
        for j in alive:
            if j == r:
                continue
            d2 = (data[_X, j] - x) ** 2 + (data[_Y, j] - y) ** 2
            if d2 > radius2 or (m == k_max and d2 >= near_d2[m - 1]):
                continue
            pos = m if m < k_max else k_max - 1
            while pos > 0 and near_d2[pos - 1] > d2:
                if pos < k_max:
                    near_d2[pos], near_row[pos] = near_d2[pos - 1], near_row[pos - 1]
                pos -= 1
            near_d2[pos], near_row[pos] = d2, j
            m = min(m + 1, k_max)
        neighbours[i] = 0.0
        neighbour_mask[i] = 0.0
        for q in range(m):
            j = near_row[q]
            dx, dy = data[_X, j] - x, data[_Y, j] - y
            rel = data[_H, j] - h
            cr, sr = math.cos(rel), math.sin(rel)
            nv = data[_SPEED, j]
            neighbours[i, q, 0] = c * dx + s * dy
            neighbours[i, q, 1] = c * dy - s * dx
            neighbours[i, q, 2] = cr
            neighbours[i, q, 3] = sr
            # Relative velocity in the ego frame.
            neighbours[i, q, 4] = nv * cr - speed
            neighbours[i, q, 5] = nv * sr
            neighbours[i, q, 6] = data[_LENGTH, j]
            neighbours[i, q, 7] = data[_WIDTH, j]
            neighbours[i, q, 8] = 1.0 if role[j] == _PEDESTRIAN else 0.0
            neighbour_mask[i, q] = 1.0

        # Indices past a path's end clip onto the padding rows, which are marked invalid.
        for q in range(offsets.shape[0]):
            flat = a * stride + min(route_index[a] + offsets[q], stride - 1)
            for p in range(waypoints.shape[1]):
                if flat_valid[flat, p]:
                    dx, dy = flat_paths[flat, p, 0] - x, flat_paths[flat, p, 1] - y
                    waypoints[i, p, q, 0] = c * dx + s * dy
                    waypoints[i, p, q, 1] = c * dy - s * dx
                    waypoints[i, p, q, 2] = wrap_scalar(flat_paths[flat, p, 2] - h)
                    waypoint_mask[i, p, q] = 1.0
                else:
                    waypoints[i, p, q] = 0.0
                    waypoint_mask[i, p, q] = 0.0

        if goal_kind[a] != 0:
            dx, dy = goal_xy[a, 0] - x, goal_xy[a, 1] - y
            goal[i, 0] = c * dx + s * dy
            goal[i, 1] = c * dy - s * dx
            goal[i, 3] = 1.0
        else:
            goal[i, 0] = goal[i, 1] = goal[i, 3] = 0.0
        goal[i, 2] = route_length[a] - route_progress[a]

        signal[i] = 0.0
        here = a * stride + route_index[a]
        via = signal_via.ravel()[here]
        if via >= 0 and via_colour[via] > 0:
            signal[i, via_colour[via] - 1] = 1.0  # colours RED=1, YELLOW=2, GREEN=3
            signal[i, 3] = max(signal_s.ravel()[here] - route_progress[a], 0.0)
        for e in range(events.shape[1]):
            events_out[i, e] = events[a, e]


_X, _Y, _H = COLUMN["x"], COLUMN["y"], COLUMN["heading"]
_SPEED, _ACCEL, _JERK = COLUMN["speed"], COLUMN["accel"], COLUMN["jerk"]
_LAT_ACCEL, _YAW_RATE, _STEERING = COLUMN["lat_accel"], COLUMN["yaw_rate"], COLUMN["steering"]
_LANE_HEADING, _T = COLUMN["lane_heading"], COLUMN["t"]
_LENGTH, _WIDTH = COLUMN["length"], COLUMN["width"]
_PEDESTRIAN = int(Role.PEDESTRIAN)
