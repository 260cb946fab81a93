"""Per-step events, computed for all vehicles at once.

Each function takes arrays (rows of the vehicle table, map lookups) and returns boolean arrays; which
events end an episode is decided by the scenario's ``events.terminate_on`` list, not here.
"""

from __future__ import annotations

import math
from enum import IntEnum
from typing import NamedTuple

import numpy as np

from smarts.compiled import njit
from smarts.core.vehicle_table import COLUMN
from smarts.maps.drivable import on_road_at


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


@njit(nogil=True, inline="always")
def _corners(x, y, heading, length, width, out):  # pragma: no cover - compiled
    """Write a box's corners (front-left, front-right, rear-right, rear-left) into out[4, 2]."""
    c, s = math.cos(heading), math.sin(heading)
    fx, fy = 0.5 * length * c, 0.5 * length * s
    lx, ly = -0.5 * width * s, 0.5 * width * c
    out[0, 0], out[0, 1] = x + fx + lx, y + fy + ly
    out[1, 0], out[1, 1] = x + fx - lx, y + fy - ly
    out[2, 0], out[2, 1] = x - fx - lx, y - fy - ly
    out[3, 0], out[3, 1] = x - fx + lx, y - fy + ly


@njit(nogil=True)
def _separated_on_axes(a, b):  # pragma: no cover - compiled
    """Whether one of a's two edge directions separates boxes a and b (corners [4, 2])."""
    for e in range(2):
        ax, ay = a[e + 1, 0] - a[e, 0], a[e + 1, 1] - a[e, 1]
        amin = amax = a[0, 0] * ax + a[0, 1] * ay
        bmin = bmax = b[0, 0] * ax + b[0, 1] * ay
        for k in range(1, 4):
            pa = a[k, 0] * ax + a[k, 1] * ay
            pb = b[k, 0] * ax + b[k, 1] * ay
            amin, amax = min(amin, pa), max(amax, pa)
            bmin, bmax = min(bmin, pb), max(bmax, pb)
        if amax < bmin or bmax < amin:
            return True
    return False


@njit(nogil=True)
def boxes_overlap(a, b):  # pragma: no cover - compiled
    """Separating axis test of two oriented boxes given by their corners [4, 2]."""
    return not (_separated_on_axes(a, b) or _separated_on_axes(b, a))


@njit(nogil=True)
def _all_pairs(corners, x, y, radius, hit):  # pragma: no cover - compiled
    n = x.shape[0]
    for i in range(n):
        for j in range(i + 1, n):
            dx, dy, reach = x[i] - x[j], y[i] - y[j], radius[i] + radius[j]
            if dx * dx + dy * dy < reach * reach and boxes_overlap(corners[i], corners[j]):
                hit[i] = True
                hit[j] = True


def box_collisions(corners: np.ndarray, x: np.ndarray, y: np.ndarray, radius: np.ndarray) -> np.ndarray:
    """Which of n oriented boxes overlap another box. Returns bool[n].

    ``corners`` is float64[n, 4, 2] (from ``VehicleTable.corners``), ``radius`` each box's half
    diagonal: a circle test picks candidate pairs, the separating axis test decides.
    """
    hit = np.zeros(len(x), dtype=bool)
    _all_pairs(
        np.ascontiguousarray(corners, dtype=np.float64),
        np.ascontiguousarray(x, dtype=np.float64),
        np.ascontiguousarray(y, dtype=np.float64),
        np.ascontiguousarray(radius, dtype=np.float64),
        hit,
    )
    return hit


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
        out = np.empty(len(rows), dtype=bool)
        for i, r in enumerate(np.asarray(rows).tolist()):
            out[i] = not_moving_step(self.anchor, self.anchor_time, r, x[i], y[i], time, self.seconds, self.distance)
        return out


@njit(nogil=True, inline="always")
def not_moving_step(anchor, anchor_time, row, x, y, time, seconds, distance):  # pragma: no cover
    """Move the row's anchor if it got farther than ``distance``; True if stuck for ``seconds``."""
    dx, dy = x - anchor[row, 0], y - anchor[row, 1]
    if dx * dx + dy * dy > distance * distance:
        anchor[row, 0], anchor[row, 1], anchor_time[row] = x, y, time
    return anchor_time[row] <= time - seconds + 1e-9


class EventTables(NamedTuple):
    """What ``episode_events`` reads and writes: the simulation's arrays under ``SimTables``'s names
    (``smarts.core.sim_records``), gathered once per call by ``event_tables``."""

    data: np.ndarray
    lane: np.ndarray
    anchor: np.ndarray
    anchor_time: np.ndarray
    lane_road: np.ndarray
    lane_internal: np.ndarray
    lane_length: np.ndarray
    lane_width: np.ndarray
    lane_succ_offsets: np.ndarray
    raster_flat: np.ndarray
    raster_base: np.ndarray
    raster_width: np.ndarray
    raster_origin: np.ndarray
    raster_inv_res: np.ndarray
    raster_cell_max: np.ndarray
    on_route_road: np.ndarray
    goal_kind: np.ndarray
    goal_xy: np.ndarray
    goal_radius: np.ndarray
    goal_road: np.ndarray
    goal_lane: np.ndarray
    goal_s: np.ndarray
    goal_gate: np.ndarray
    agent_events: np.ndarray
    agent_done: np.ndarray
    prev_xy: np.ndarray
    prev_row: np.ndarray
    episode_map: np.ndarray
    episode_step: np.ndarray
    episode_limit: np.ndarray
    terminate_on: np.ndarray
    not_moving_seconds: np.ndarray
    not_moving_distance: np.ndarray


_END_MARGIN = 0.5
"""Metres short of a dead-end lane's end at which a vehicle's front counts as having reached it."""


@njit(nogil=True)
def event_tables(tables):  # pragma: no cover - compiled
    """The ``EventTables`` of a frozen ``SimTables`` (read once per kernel call: the per-episode
    calls then pass values, not the record)."""
    t = tables
    return EventTables(
        data=t.data,
        lane=t.lane,
        anchor=t.anchor,
        anchor_time=t.anchor_time,
        lane_road=t.lane_road,
        lane_internal=t.lane_internal,
        lane_length=t.lane_length,
        lane_width=t.lane_width,
        lane_succ_offsets=t.lane_succ_offsets,
        raster_flat=t.raster_flat,
        raster_base=t.raster_base,
        raster_width=t.raster_width,
        raster_origin=t.raster_origin,
        raster_inv_res=t.raster_inv_res,
        raster_cell_max=t.raster_cell_max,
        on_route_road=t.on_route_road,
        goal_kind=t.goal_kind,
        goal_xy=t.goal_xy,
        goal_radius=t.goal_radius,
        goal_road=t.goal_road,
        goal_lane=t.goal_lane,
        goal_s=t.goal_s,
        goal_gate=t.goal_gate,
        agent_events=t.agent_events,
        agent_done=t.agent_done,
        prev_xy=t.prev_xy,
        prev_row=t.prev_row,
        episode_map=t.episode_map,
        episode_step=t.episode_step,
        episode_limit=t.episode_limit,
        terminate_on=t.terminate_on,
        not_moving_seconds=t.not_moving_seconds,
        not_moving_distance=t.not_moving_distance,
    )


@njit(nogil=True)
def agent_events(tables, alive, agents, rows, b, time):  # pragma: no cover - compiled
    """``episode_events`` from a frozen ``SimTables`` (the entry from Python)."""
    episode_events(event_tables(tables), alive, agents, rows, b, time)


@njit(nogil=True)
def events_by_episode(
    tables,
    alive,
    agents,
    rows,
    episodes,
    alive_lo,
    alive_hi,
    agent_lo,
    agent_hi,
    episode_time,
):  # pragma: no cover - compiled
    """``episode_events`` of each episode in ``episodes`` with only that episode's rows as others
    (``alive[alive_lo[b]:alive_hi[b]]``), its agents ``agents[agent_lo[b]:agent_hi[b]]`` and its
    clock; it reads the episode's map, raster and event rules from ``tables`` (the simulation's
    frozen ``SimTables``, gathered once here).

    In this module with the kernel it calls: numba's cache of a compiled function holds the code
    of what it calls but is dropped only when its own file changes."""
    et = event_tables(tables)
    for k in range(episodes.shape[0]):
        b = episodes[k]
        lo, hi = agent_lo[b], agent_hi[b]
        if lo == hi:
            continue
        episode_events(et, alive[alive_lo[b] : alive_hi[b]], agents[lo:hi], rows[lo:hi], b, episode_time[b])


@njit(nogil=True)
def episode_events(et, alive, agents, rows, b, time):  # pragma: no cover - compiled
    """Every event of ``Event`` for the agents ``agents`` (rows ``rows``) of episode ``b`` at its
    clock ``time``, from and into ``et`` (``EventTables``): its ``agent_events`` and
    ``agent_done`` rows of these agents are written here.

    Collisions are tested against all ``alive`` rows (circle pre-test, then separating axes).
    Off road is read from the drivable raster of the episode's map. Goal kinds: 1 = within
    ``goal_radius`` of ``goal_xy``; 2 = on ``goal_road`` (and ``goal_lane`` unless it is -1) at
    or past ``goal_s``.

    Goals are tested on the whole movement since the last call (``prev_xy`` of the agent's
    ``prev_row``; both are updated here), not only at the new position: a position goal is
    reached when that segment passes within the radius, a road goal when it crosses the goal
    line (``goal_gate``) forwards. A lane shorter than one step's travel is otherwise jumped over
    and its goal never seen. Off route is not flagged on the step the goal is reached (the route
    ends at the goal; what lies beyond it is off the route).

    The end of the map is not the edge of the road: a vehicle whose front reaches the end of a
    lane of its route that leads nowhere (no successor), still within the lane's width, has left
    the map, as SUMO removes a vehicle at its route's end. Its episode ends there (done, by no
    terminal event: truncated, like the step limit), without off-road flags for that step.
    """
    data, lane = et.data, et.lane
    m = et.episode_map[b]
    flat_raster = et.raster_flat[et.raster_base[m] : et.raster_base[m + 1]]
    raster_width, raster_origin = et.raster_width[m], et.raster_origin[m]
    inv_res, cell_max = et.raster_inv_res[m], et.raster_cell_max[m]
    lane_internal, lane_road, on_route_road = et.lane_internal, et.lane_road, et.on_route_road
    terminate_on = et.terminate_on[b]
    at_step_limit = et.episode_step[b] >= et.episode_limit[b]
    not_moving_seconds, not_moving_distance = et.not_moving_seconds[b], et.not_moving_distance[b]
    prev_xy, prev_row, events, done = et.prev_xy, et.prev_row, et.agent_events, et.agent_done
    anchor, anchor_time = et.anchor, et.anchor_time
    own = np.empty((4, 2))
    other = np.empty((4, 2))
    for i in range(agents.shape[0]):
        a, r = agents[i], rows[i]
        ev = events[a]
        ev[:] = False
        x, y, h = data[_X, r], data[_Y, r], data[_H, r]
        length, width = data[_LENGTH, r], data[_WIDTH, r]
        _corners(x, y, h, length, width, own)
        ev[COLLISION] = _collides(data, alive, r, x, y, 0.5 * math.hypot(length, width), own, other)
        ev[OFF_ROAD] = not on_road_at(flat_raster, raster_width, raster_origin, inv_res, cell_max, x, y)
        ev[PARTIAL_OFF_ROAD] = _corner_off_road(flat_raster, raster_width, raster_origin, inv_res, cell_max, own)
        ln = lane[r]
        road = lane_road[ln] if ln >= 0 else -1
        left_map = (ev[OFF_ROAD] or ev[PARTIAL_OFF_ROAD]) and _at_dead_end(et, a, r, ln, road, length)
        if left_map:
            ev[OFF_ROAD] = ev[PARTIAL_OFF_ROAD] = False
        if ln >= 0 and not lane_internal[ln]:  # junction lanes cross each other: no direction
            ev[WRONG_WAY] = math.cos(h - data[_LANE_HEADING, r]) < 0.0
            ev[OFF_ROUTE] = not on_route_road[a, road]
        px, py = (prev_xy[a, 0], prev_xy[a, 1]) if prev_row[a] == r else (x, y)
        prev_xy[a, 0], prev_xy[a, 1], prev_row[a] = x, y, r
        ev[REACHED_GOAL] = _reached_goal(et, a, r, ln, road, px, py, x, y)
        if ev[REACHED_GOAL]:
            ev[OFF_ROUTE] = False
        ev[NOT_MOVING] = not_moving_step(anchor, anchor_time, r, x, y, time, not_moving_seconds, not_moving_distance)
        ev[MAX_STEPS] = at_step_limit
        finished = at_step_limit or left_map
        for e in range(ev.shape[0]):
            finished |= ev[e] and terminate_on[e]
        done[a] = finished


# The per-agent tests of ``episode_events``, inlined into it by numba (no call per agent).
@njit(nogil=True, inline="always")
def _collides(data, alive, r, x, y, radius, own, other):  # pragma: no cover - compiled
    """Whether row ``r`` (box corners ``own``, bounding ``radius``) overlaps another ``alive`` row:
    a circle pre-test, then separating axes (``other`` is scratch for the other box's corners)."""
    for j in alive:
        if j == r:
            continue
        dx, dy = data[_X, j] - x, data[_Y, j] - y
        reach = radius + 0.5 * math.hypot(data[_LENGTH, j], data[_WIDTH, j])
        if dx * dx + dy * dy >= reach * reach:
            continue
        _corners(data[_X, j], data[_Y, j], data[_H, j], data[_LENGTH, j], data[_WIDTH, j], other)
        if boxes_overlap(own, other):
            return True
    return False


@njit(nogil=True, inline="always")
def _corner_off_road(flat_raster, raster_width, raster_origin, inv_res, cell_max, own):  # pragma: no cover - compiled
    """Whether any of the four box corners ``own`` lies off the drivable raster."""
    off = False
    for k in range(4):
        if not on_road_at(flat_raster, raster_width, raster_origin, inv_res, cell_max, own[k, 0], own[k, 1]):
            off = True
    return off


@njit(nogil=True, inline="always")
def _at_dead_end(et, a, r, ln, road, length):  # pragma: no cover - compiled
    """Whether row ``r``'s front has reached the end of a lane of agent ``a``'s route that leads
    nowhere, still within the lane's width (it has left the map, not the road)."""
    data = et.data
    return (
        ln >= 0
        and et.lane_succ_offsets[ln + 1] == et.lane_succ_offsets[ln]
        and et.on_route_road[a, road]
        and data[_S, r] + 0.5 * length >= et.lane_length[ln] - _END_MARGIN
        and abs(data[_T, r]) <= 0.5 * et.lane_width[ln]
    )


@njit(nogil=True, inline="always")
def _reached_goal(et, a, r, ln, road, px, py, x, y):  # pragma: no cover - compiled
    """Whether agent ``a`` (row ``r``, moved from (px, py) to (x, y)) reached its goal this step:
    kind 1 passes within the radius of the point, kind 2 is on the goal road (and lane) past
    ``goal_s`` or crosses the goal line forwards."""
    if et.goal_kind[a] == 1:
        radius = et.goal_radius[a]
        return segment_point_distance2(px, py, x, y, et.goal_xy[a, 0], et.goal_xy[a, 1]) <= radius * radius
    if et.goal_kind[a] == 2:
        goal_lane = et.goal_lane[a]
        return (
            ln >= 0
            and road == et.goal_road[a]
            and (goal_lane < 0 or ln == goal_lane)
            and et.data[_S, r] >= et.goal_s[a]
        ) or crosses_gate(px, py, x, y, et.goal_gate[a])
    return False


@njit(nogil=True, inline="always")
def segment_point_distance2(x0, y0, x1, y1, px, py):  # pragma: no cover - compiled
    """Squared distance from point (px, py) to the segment (x0, y0)-(x1, y1)."""
    dx, dy = x1 - x0, y1 - y0
    n2 = dx * dx + dy * dy
    f = 0.0 if n2 <= 0.0 else min(max(((px - x0) * dx + (py - y0) * dy) / n2, 0.0), 1.0)
    ex, ey = x0 + f * dx - px, y0 + f * dy - py
    return ex * ex + ey * ey


@njit(nogil=True, inline="always")
def crosses_gate(x0, y0, x1, y1, gate):  # pragma: no cover - compiled
    """Whether moving from (x0, y0) to (x1, y1) crosses a goal line forwards: from behind it to
    on or past it, between its ends. ``gate``: x, y, unit direction dx, dy, lateral lo, hi."""
    gx, gy, dx, dy, lo, hi = gate[0], gate[1], gate[2], gate[3], gate[4], gate[5]
    a0 = (x0 - gx) * dx + (y0 - gy) * dy
    a1 = (x1 - gx) * dx + (y1 - gy) * dy
    if not (a0 < 0.0 <= a1):
        return False
    f = a0 / (a0 - a1)
    qx, qy = x0 + f * (x1 - x0) - gx, y0 + f * (y1 - y0) - gy
    u = -qx * dy + qy * dx  # along the left normal (-dy, dx)
    return lo <= u <= hi


_X, _Y, _H = COLUMN["x"], COLUMN["y"], COLUMN["heading"]
_LENGTH, _WIDTH = COLUMN["length"], COLUMN["width"]
_S, _T, _LANE_HEADING = COLUMN["s"], COLUMN["t"], COLUMN["lane_heading"]
# Plain ints for the compiled code (IntEnum members are Python objects).
(COLLISION, OFF_ROAD, PARTIAL_OFF_ROAD, WRONG_WAY, OFF_ROUTE, REACHED_GOAL, NOT_MOVING, MAX_STEPS) = (
    int(e) for e in Event
)
