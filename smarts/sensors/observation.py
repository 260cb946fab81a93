"""The observation, built for every agent of one interface group in one batched pass.

Everything is expressed in the ego frame (x forward, y left, headings relative to the ego's), so a
policy is invariant to where on the map it drives. Shapes are fixed by the agent's interface
(``smarts.sensors.interface.AgentInterface``); masks mark padding.

Per agent, with the default interface:
- ``ego`` float32[12]: speed (m/s), longitudinal acceleration (m/s^2), longitudinal jerk (m/s^3),
  lateral acceleration (m/s^2), yaw rate (rad/s), steering (rad), heading error to the lane (rad),
  lateral offset from the lane centre (m, + left), lane width (m), lane speed limit (m/s), vehicle
  length (m), vehicle width (m). ``ego.extended`` appends the angular acceleration (rad/s^2, the
  change of yaw rate over the last step).
- ``neighbours`` float32[K, 9]: the K nearest road users within ``neighbours.radius``: dx, dy (m),
  cos and sin of the relative heading, relative velocity vx, vy (m/s, ego frame), length, width
  (m), 1 for a pedestrian (0 for a vehicle). ``neighbours.extended`` appends speed (m/s),
  acceleration (m/s^2), yaw rate (rad/s), lane index on its road (0 = rightmost, -1 off the map),
  1 if on the ego's road, and a one-hot of the type (passenger, bus, truck, motorcycle,
  pedestrian). With occlusion on, a last column holds the visible fraction (0..1, see
  ``smarts.sensors.occlusion``); in ``hide`` mode fully hidden road users are not listed.
  ``neighbour_feature_names(interface)`` names the columns.
- ``neighbour_mask`` float32[K]: 1 where a neighbour is present.
- ``waypoints`` float32[3, W, 3]: paths along the route (0), the lane left of it (1) and right of it
  (2), W points ``waypoints.spacing`` route points apart: x, y (m), relative heading (rad).
- ``waypoint_mask`` float32[3, W].
- ``goal`` float32[4]: goal dx, dy (m), route distance left (m), 1 if the mission has a goal.
- ``signal`` float32[4] (``signals: true``): the next traffic signal on the route: red, yellow,
  green (one of them 1, all 0 when there is none ahead) and the route distance to its stop line (m,
  0 when none).
- ``events`` float32[8]: the events of ``smarts.core.events.Event`` this step, 0/1.
- ``lead`` float32[12] (``lead: true``): the vehicle the agent follows (``mission.follow``), as
  ``smarts.core.following`` sees it: present, visible (within 50 m), in my lane (lane continuity),
  dx, dy (m, ego frame), cos and sin of the relative heading, relative velocity vx, vy (m/s, ego
  frame), lead speed (m/s), lead acceleration (m/s^2), bumper-to-bumper gap (m, along the lane
  when in lane, else along the ego's heading). Everything after the flags is 0 when the lead is
  not visible. ``LEAD_FEATURE_NAMES`` names the columns.
- ``ahead`` float32[5] (``ahead: true``): the nearest road user ahead on the agent's lane or a lane
  it leads to (lane continuity, within 50 m of lane): present, bumper-to-bumper gap along the lanes
  (m; 50 when none), its speed minus the agent's (m/s), its speed (m/s) and acceleration (m/s^2).
Optional sensors add keys: ``rasters`` and ``rgb`` (``smarts.sensors.rasters``), ``lidar`` and
``lidar_hit`` (``smarts.sensors.lidar``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import NamedTuple

import gymnasium as gym
import numpy as np

from smarts.compiled import njit
from smarts.core.events import NUM_EVENTS
from smarts.core.following import ahead_state, lead_state
from smarts.core.geometry import wrap_scalar
from smarts.core.sim_records import sim_tables
from smarts.core.simulation import Simulation
from smarts.core.vehicle_table import COLUMN, Role, VehicleType
from smarts.records import declare, freeze_fields
from smarts.sensors.interface import (
    AgentInterface,
    NeighboursInterface,
    WaypointsInterface,
)
from smarts.sensors.lidar import LidarSensor
from smarts.sensors.occlusion import ShadowCaster, Shadows
from smarts.sensors.rasters import RasterSensor, RoutePaths

EGO_FEATURES = 12
NEIGHBOUR_FEATURES = 9
GOAL_FEATURES = 4
SIGNAL_FEATURES = 4
NUM_PATHS = 3
# agents/obs_columns.py names these columns for the agents (which import no simulator); a test keeps them equal.
EGO_FEATURE_NAMES = (
    "speed", "accel", "jerk", "lat_accel", "yaw_rate", "steering", "heading_error", "lane_offset",
    "lane_width", "speed_limit", "length", "width",
)  # fmt: skip
NEIGHBOUR_FEATURE_NAMES = ("dx", "dy", "cos_heading", "sin_heading", "vx", "vy", "length", "width", "pedestrian")
EXTENDED_NEIGHBOUR_FEATURE_NAMES = (
    "speed", "accel", "yaw_rate", "lane_index", "same_road",
    *(f"type_{t.name.lower()}" for t in VehicleType),
)  # fmt: skip
GOAL_FEATURE_NAMES = ("dx", "dy", "route_left", "has_goal")
SIGNAL_FEATURE_NAMES = ("red", "yellow", "green", "stop_distance")
WAYPOINT_FEATURE_NAMES = ("x", "y", "heading")
PATH_NAMES = ("route", "left", "right")
"""The paths of ``waypoints`` (its first index): along the route, the lanes left and right of it."""
AHEAD_FEATURE_NAMES = ("present", "gap", "rel_speed", "speed", "accel")
LEAD_FEATURE_NAMES = (
    "present", "visible", "in_lane", "dx", "dy", "cos_heading", "sin_heading", "vx", "vy", "speed",
    "accel", "gap",
)  # fmt: skip
_VIS_OFF, _VIS_HIDE, _VIS_FLAG = 0, 1, 2


class ObserveSetup(NamedTuple):
    """What one builder's observation kernel reads besides the simulation: its interface's
    sizes and switches, and the yaw rates it remembers per agent (built once per builder)."""

    offsets: np.ndarray  # int64[W] route points between waypoints
    radius2: float  # squared neighbour radius
    extended: bool  # extended neighbour columns
    vis_mode: int  # _VIS_OFF, _VIS_HIDE or _VIS_FLAG
    ego_extended: bool  # the angular acceleration column
    yaw: np.ndarray  # float64[3, A] yaw rate seen, its step, angular acceleration (ego_extended)


class BasicObservation(NamedTuple):
    """The basic keys of one call's observation (``ObservationBuilder.empty_basic``), filled by
    the kernel."""

    ego: np.ndarray
    neighbours: np.ndarray
    neighbour_mask: np.ndarray
    waypoints: np.ndarray
    waypoint_mask: np.ndarray
    goal: np.ndarray
    signal: np.ndarray
    events: np.ndarray


# The records ``_observe`` builds for its per-agent blocks, so names travel with the arrays; built in
# compiled code only (tuples, free to pass there), they are never frozen, so not declared.
class RoadUsers(NamedTuple):
    """What the neighbours block reads of every row and lane (built once per ``_observe`` call)."""

    data: np.ndarray  # float64[columns, rows] the vehicle table
    lane: np.ndarray  # int32[rows] projected lane, -1 off every lane
    role: np.ndarray  # int8[rows]
    vtype: np.ndarray  # int8[rows]
    lane_index: np.ndarray  # int16[L] position on its road, 0 = rightmost
    lane_road: np.ndarray  # int32[L]


class NeighbourColumns(NamedTuple):
    """The interface's switches of optional ``neighbours`` columns (built once per ``_observe`` call)."""

    extended: bool  # the extended columns
    vis_mode: int  # _VIS_OFF, _VIS_HIDE or _VIS_FLAG: _VIS_FLAG adds the visible fraction


class EgoPose(NamedTuple):
    """The observing agent as its blocks see it (built per agent inside ``_observe``)."""

    x: float
    y: float
    h: float  # heading
    c: float  # cos h
    s: float  # sin h
    speed: float
    lane: int  # -1: off every lane


declare(ObserveSetup)


@njit(nogil=True)
def _freeze(fields):  # pragma: no cover - compiled
    """The frozen record of this module's records (see ``smarts.records``)."""
    return freeze_fields(fields)


@dataclass(frozen=True)
class ObservationConfig:
    """The basic observation's sizes (kept for existing callers; an ``AgentInterface`` says more)."""

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
            raise ValueError(f"observation.neighbour_radius: expected a positive number, got {self.neighbour_radius!r}")

    def interface(self) -> AgentInterface:
        return AgentInterface(
            neighbours=NeighboursInterface(count=self.neighbours, radius=float(self.neighbour_radius)),
            waypoints=WaypointsInterface(count=self.waypoints, spacing=self.waypoint_spacing),
        )


def as_interface(config: AgentInterface | ObservationConfig | None) -> AgentInterface:
    """An interface from either form (None: the default interface)."""
    if config is None:
        return AgentInterface()
    if isinstance(config, ObservationConfig):
        return config.interface()
    if isinstance(config, AgentInterface):
        return config
    raise TypeError(f"expected an AgentInterface or ObservationConfig, got {type(config).__name__}")


def ego_feature_names(interface: AgentInterface) -> tuple[str, ...]:
    """Names of the ``ego`` columns, in order."""
    return EGO_FEATURE_NAMES + (("angular_accel",) if interface.ego.extended else ())


def neighbour_feature_names(interface: AgentInterface) -> tuple[str, ...]:
    """Names of the ``neighbours`` columns, in order."""
    names = NEIGHBOUR_FEATURE_NAMES
    if interface.neighbours.extended:
        names += EXTENDED_NEIGHBOUR_FEATURE_NAMES
    if interface.occlusion.enabled:
        names += ("visible_fraction",)
    return names


def observation_space(config: AgentInterface | ObservationConfig | None = None) -> gym.spaces.Dict:
    """The observation space an interface gives."""
    interface = as_interface(config)
    return ObservationBuilder(interface).space


class ObservationBuilder:
    """Builds ``{key: array[A, ...]}`` for the agents given (all with this interface), all at once.

    The basic parts come from one compiled pass; each optional sensor is an object with
    ``spaces()`` and ``observe(...)`` whose keys are added after them (rasters, lidar). Received
    V2V messages depend on the step's actions, so the env adds them (``smarts.env.v2v``). ``stream`` separates the noise of
    builders that share a simulation (one per interface group).
    """

    def __init__(self, config: AgentInterface | ObservationConfig | None = None, stream: int = 0):
        self.interface = interface = as_interface(config)
        self.config = ObservationConfig(  # the basic sizes, for callers of the older API
            interface.neighbours.count,
            interface.neighbours.radius,
            interface.waypoints.count,
            interface.waypoints.spacing,
        )
        k, w = interface.neighbours.count, interface.waypoints.count
        self._ego_features = len(ego_feature_names(interface))
        self._neighbour_features = len(neighbour_feature_names(interface))
        self._offsets = np.arange(w) * interface.waypoints.spacing
        self._vis_mode = (
            _VIS_OFF if not interface.occlusion.enabled
            else _VIS_HIDE if interface.occlusion.mode == "hide" else _VIS_FLAG
        )  # fmt: skip
        self.shadows = ShadowCaster(interface.occlusion.range) if interface.needs_shadows else None
        hide = interface.occlusion.enabled and interface.occlusion.mode == "hide"
        self.rasters = RasterSensor(interface.rasters, hide) if interface.rasters is not None else None
        self.lidar = LidarSensor(interface.lidar, stream) if interface.lidar is not None else None
        self._no_visible = np.zeros((1, 1), dtype=np.float32)
        self._yaw = np.zeros((3, 0))  # previous yaw rate, its step, angular acceleration per agent
        self._setup = None  # frozen ObserveSetup (rebuilt when _yaw is)
        self.space = self._space(k, w)

    def _space(self, k: int, w: int) -> gym.spaces.Dict:
        def box(shape, low=-np.inf, high=np.inf):
            return gym.spaces.Box(low=low, high=high, shape=shape, dtype=np.float32)

        spaces = {
            "ego": box((self._ego_features,)),
            "neighbours": box((k, self._neighbour_features)),
            "neighbour_mask": box((k,), 0.0, 1.0),
            "waypoints": box((NUM_PATHS, w, 3)),
            "waypoint_mask": box((NUM_PATHS, w), 0.0, 1.0),
            "goal": box((GOAL_FEATURES,)),
        }
        if self.interface.signals:
            spaces["signal"] = box((SIGNAL_FEATURES,))
        spaces["events"] = box((NUM_EVENTS,), 0.0, 1.0)
        if self.interface.lead:
            spaces["lead"] = box((len(LEAD_FEATURE_NAMES),))
        if self.interface.ahead:
            spaces["ahead"] = box((len(AHEAD_FEATURE_NAMES),))
        if self.rasters is not None:
            spaces.update(self.rasters.spaces())
        if self.lidar is not None:
            spaces.update(self.lidar.spaces())
        return gym.spaces.Dict(spaces)

    def empty_basic(self, n: int) -> dict[str, np.ndarray]:
        """Uninitialised arrays of the basic keys for ``n`` agents, in the order the observation
        kernels fill them."""
        k, w = self.interface.neighbours.count, self.interface.waypoints.count
        return {
            "ego": np.empty((n, self._ego_features), dtype=np.float32),
            "neighbours": np.empty((n, k, self._neighbour_features), dtype=np.float32),
            "neighbour_mask": np.empty((n, k), dtype=np.float32),
            "waypoints": np.empty((n, NUM_PATHS, w, 3), dtype=np.float32),
            "waypoint_mask": np.empty((n, NUM_PATHS, w), dtype=np.float32),
            "goal": np.empty((n, GOAL_FEATURES), dtype=np.float32),
            "signal": np.empty((n, SIGNAL_FEATURES), dtype=np.float32),
            "events": np.empty((n, NUM_EVENTS), dtype=np.float32),
        }

    def build(self, sim: Simulation, agents: np.ndarray) -> dict[str, np.ndarray]:
        interface = self.interface
        n = len(agents)
        rows = sim.agent_row[agents]
        shadows: Shadows | None = self.shadows.scan(sim, agents, rows) if self.shadows is not None else None
        obs = self.empty_basic(n)
        if interface.ego.extended and self._yaw.shape[1] != len(sim.agent_ids):
            self._yaw = np.zeros((3, len(sim.agent_ids)))
            self._yaw[1] = -2.0
            self._setup = None
        if self._setup is None:
            self._setup = _freeze(ObserveSetup(
                offsets=self._offsets, radius2=float(interface.neighbours.radius**2),
                extended=bool(interface.neighbours.extended), vis_mode=self._vis_mode,
                ego_extended=bool(interface.ego.extended), yaw=self._yaw,
            ))  # fmt: skip
        scope = sim.scope(agents)
        visible = shadows.visible if shadows is not None and self._vis_mode != _VIS_OFF else self._no_visible
        _observe(
            sim_tables(sim), self._setup, scope.alive, scope.lo, scope.hi, scope.base, agents, rows, visible,
            BasicObservation(**obs),
        )  # fmt: skip
        if not interface.signals:
            del obs["signal"]
        if interface.lead:
            obs["lead"] = lead_features(sim, agents)
        if interface.ahead:
            st = ahead_state(sim, agents)
            obs["ahead"] = np.stack([st.present, st.gap, st.rel_speed, st.speed, st.accel], axis=1).astype(np.float32)
        if self.rasters is not None:
            obs.update(self.rasters.observe(sim, agents, rows, shadows))
        if self.lidar is not None:
            obs.update(self.lidar.observe(sim, agents, rows))
        return obs


def lead_features(sim: Simulation, agents: np.ndarray) -> np.ndarray:
    """float32[n, 12] ``lead`` block of ``agents`` (see the module docstring)."""
    st = lead_state(sim, agents)
    cols = [
        st.present, st.visible, st.in_lane, st.dx, st.dy, np.cos(st.rel_heading), np.sin(st.rel_heading),
        st.rel_vx, st.rel_vy, st.lead_speed, st.lead_accel, np.nan_to_num(st.gap, nan=0.0),
    ]  # fmt: skip
    out = np.stack(cols, axis=1).astype(np.float32)
    out[~st.visible, 3:] = 0.0
    return out


@njit(nogil=True)
def _observe(
    tables, setup, alive, alive_lo, alive_hi, row_base, agents, rows, visible, out
):  # pragma: no cover - compiled
    """The basic observation of each agent ``agents[i]`` (row ``rows[i]``) among the live rows of
    its own episode (``alive[alive_lo[i]:alive_hi[i]]``; ``visible`` is indexed by the row within
    the episode, ``row - row_base[i]``), with its episode's signal colours and step: from
    ``tables`` (a frozen ``SimTables``) and ``setup`` (a frozen ``ObserveSetup``) into ``out``
    (a ``BasicObservation``)."""
    t = tables
    data, lane, lane_width, lane_speed_limit = t.data, t.lane, t.lane_width, t.lane_speed_limit
    stride, route_index = t.stride, t.route_index
    goal_kind, goal_xy, route_length, route_progress = t.goal_kind, t.goal_xy, t.route_length, t.route_progress
    signal_via, signal_s, via_colours = t.signal_via, t.signal_s, t.via_colour
    agent_episode, events, episode_step, dt = t.agent_episode, t.agent_events, t.episode_step, t.dt
    users = RoadUsers(data=data, lane=lane, role=t.role, vtype=t.vtype, lane_index=t.lane_index, lane_road=t.lane_road)
    paths = RoutePaths(t.flat_paths, t.flat_valid, stride, t.path_len, route_index)
    offsets, radius2, vis_mode, ego_extended, yaw = (
        setup.offsets, setup.radius2, setup.vis_mode, setup.ego_extended, setup.yaw
    )  # fmt: skip
    columns = NeighbourColumns(extended=setup.extended, vis_mode=vis_mode)
    ego, goal, signal, events_out = out.ego, out.goal, out.signal, out.events
    k_max = out.neighbours.shape[1]
    near_d2 = np.empty(k_max)
    near_row = np.empty(k_max, dtype=np.int64)
    for i in range(agents.shape[0]):
        a, r = agents[i], rows[i]
        b = agent_episode[a]
        via_colour = via_colours[b]
        step = episode_step[b]
        base = row_base[i]
        x, y, h = data[_X, r], data[_Y, r], data[_H, r]
        c, s = math.cos(h), math.sin(h)
        speed = data[_SPEED, r]

        ln = lane[r]
        pose = EgoPose(x=x, y=y, h=h, c=c, s=s, speed=speed, lane=ln)
        _ego_features(data, r, ln, lane_width, lane_speed_limit, h, speed, ego, i)
        if ego_extended:
            # yaw[0]: yaw rate seen at step yaw[1]; yaw[2]: angular acceleration at that step.
            if yaw[1, a] != step:
                yaw[2, a] = (data[_YAW_RATE, r] - yaw[0, a]) / dt if yaw[1, a] == step - 1 else 0.0
                yaw[0, a], yaw[1, a] = data[_YAW_RATE, r], step
            ego[i, 12] = yaw[2, a]

        m = _nearest_rows(data, alive[alive_lo[i] : alive_hi[i]], r, x, y, radius2, vis_mode == _VIS_HIDE, visible, i,
                          base, near_d2, near_row)  # fmt: skip
        _neighbour_features(users, pose, near_row, m, columns, visible, base, out, i)
        _waypoint_features(paths, offsets, a, pose, out, i)

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
        via = signal_via[here]
        if via >= 0 and via_colour[via] > 0:
            signal[i, via_colour[via] - 1] = 1.0  # colours RED=1, YELLOW=2, GREEN=3
            signal[i, 3] = max(signal_s[here] - route_progress[a], 0.0)
        for e in range(events.shape[1]):
            events_out[i, e] = events[a, e]


# The blocks of ``_observe`` per agent, inlined into it by numba; they take plain arrays or tuples
# built by ``_observe``, not the frozen records (``smarts.records``: a field read per agent
# would cost a load and a reference).
@njit(nogil=True, inline="always")
def _ego_features(data, r, ln, lane_width, lane_speed_limit, h, speed, ego, i):  # pragma: no cover - compiled
    """The ego block's first 12 columns of row ``r`` (lane ``ln``, -1: off every lane) into ``ego[i]``."""
    ego[i, 0] = speed
    ego[i, 1] = data[_ACCEL, r]
    ego[i, 2] = data[_JERK, r]
    ego[i, 3] = data[_LAT_ACCEL, r]
    ego[i, 4] = data[_YAW_RATE, r]
    ego[i, 5] = data[_STEERING, r]
    ego[i, 6] = wrap_scalar(h - data[_LANE_HEADING, r])
    ego[i, 7] = data[_T, r]
    ego[i, 8] = lane_width[ln] if ln >= 0 else 0.0
    ego[i, 9] = lane_speed_limit[ln] if ln >= 0 else 0.0
    ego[i, 10] = data[_LENGTH, r]
    ego[i, 11] = data[_WIDTH, r]


@njit(nogil=True, inline="always")
def _nearest_rows(
    data, alive, r, x, y, radius2, hide, visible, i, base, near_d2, near_row
):  # pragma: no cover - compiled
    """The up to K (``near_row.shape[0]``) nearest ``alive`` rows to (x, y) within the radius,
    nearest first, into ``near_d2``/``near_row``; returns how many. ``hide``: leave out rows
    agent ``i`` cannot see at all."""
    k_max = near_row.shape[0]
    # K nearest by insertion into a sorted list (K is small); equal distances keep row order.
    m = 0
    for j in alive:
        if j == r:
            continue
        d2 = (data[_X, j] - x) ** 2 + (data[_Y, j] - y) ** 2
        if d2 > radius2 or (m == k_max and d2 >= near_d2[m - 1]):
            continue
        if hide and visible[i, j - base] <= 0.0:
            continue
        pos = m if m < k_max else k_max - 1
        while pos > 0 and near_d2[pos - 1] > d2:
            if pos < k_max:
                near_d2[pos], near_row[pos] = near_d2[pos - 1], near_row[pos - 1]
            pos -= 1
        near_d2[pos], near_row[pos] = d2, j
        m = min(m + 1, k_max)
    return m


@njit(nogil=True, inline="always")
def _neighbour_features(users, pose, near_row, m, columns, visible, base, out, i):  # pragma: no cover - compiled
    """The neighbours block of agent ``i`` (``pose``, an ``EgoPose``) into ``out`` (a
    ``BasicObservation``): one row per nearest road user (``near_row[:m]``, from ``users``, a
    ``RoadUsers``) in the ego frame, the rest zero; ``columns`` (``NeighbourColumns``) says which."""
    data, lane, role, vtype, lane_index, lane_road = (
        users.data, users.lane, users.role, users.vtype, users.lane_index, users.lane_road
    )  # fmt: skip
    x, y, h, c, s, speed, ln = pose.x, pose.y, pose.h, pose.c, pose.s, pose.speed, pose.lane
    extended, vis_mode = columns.extended, columns.vis_mode
    neighbours, neighbour_mask = out.neighbours, out.neighbour_mask
    vis_col = neighbours.shape[2] - 1
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
        if extended:
            neighbours[i, q, 9] = nv
            neighbours[i, q, 10] = data[_ACCEL, j]
            neighbours[i, q, 11] = data[_YAW_RATE, j]
            lj = lane[j]
            neighbours[i, q, 12] = float(lane_index[lj]) if lj >= 0 else -1.0
            neighbours[i, q, 13] = 1.0 if lj >= 0 and ln >= 0 and lane_road[lj] == lane_road[ln] else 0.0
            if 0 <= vtype[j] < _NUM_TYPES:
                neighbours[i, q, 14 + vtype[j]] = 1.0
        if vis_mode != _VIS_OFF:
            neighbours[i, q, vis_col] = visible[i, j - base]
        neighbour_mask[i, q] = 1.0


@njit(nogil=True, inline="always")
def _waypoint_features(paths, offsets, a, pose, out, i):  # pragma: no cover - compiled
    """The waypoints of agent ``a`` at each offset from its route point along each of its paths
    (``paths``, a ``smarts.sensors.rasters.RoutePaths``), in the frame of ``pose`` (an
    ``EgoPose``), into row ``i`` of ``out`` (a ``BasicObservation``)."""
    flat_paths, flat_valid, stride, index = paths.flat_paths, paths.flat_valid, paths.stride, paths.route_index[a]
    x, y, h, c, s = pose.x, pose.y, pose.h, pose.c, pose.s
    waypoints, waypoint_mask = out.waypoints, out.waypoint_mask
    # Indices past a path's end clip onto the padding rows, which are marked invalid.
    for q in range(offsets.shape[0]):
        flat = a * stride + min(index + offsets[q], stride - 1)
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


_X, _Y, _H = COLUMN["x"], COLUMN["y"], COLUMN["heading"]
_SPEED, _ACCEL, _JERK = COLUMN["speed"], COLUMN["accel"], COLUMN["jerk"]
_LAT_ACCEL, _YAW_RATE, _STEERING = COLUMN["lat_accel"], COLUMN["yaw_rate"], COLUMN["steering"]
_LANE_HEADING, _T = COLUMN["lane_heading"], COLUMN["t"]
_LENGTH, _WIDTH = COLUMN["length"], COLUMN["width"]
_PEDESTRIAN = int(Role.PEDESTRIAN)
_NUM_TYPES = len(VehicleType)
