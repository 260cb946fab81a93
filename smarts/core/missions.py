"""Turn a scenario's mission specs into arrays the step loop can use.

A mission is resolved once per reset into: a start pose on its lane, a lane-level route, a dense route
path (~1 m spacing) with the paths of the lanes left and right of it, and a goal test. The step loop
then only gathers from these padded per-agent arrays.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from smarts.core.errors import MapError
from smarts.maps import RoadMap, extend_route, project, route_polyline, route_roads, shortest_route

GOAL_NONE, GOAL_POSITION, GOAL_ROAD = 0, 1, 2
ENDLESS_ROUTE_LENGTH = 2000.0  # metres of route planned ahead for missions without a goal


@dataclass
class ResolvedMission:
    agent_id: str
    start_lane: int
    start_xy: np.ndarray  # float64[2]
    start_heading: float
    start_speed: float
    route: np.ndarray  # int32 lane sequence
    path_xy: np.ndarray  # float64[n, 2] along the route
    path_heading: np.ndarray  # float64[n]
    path_s: np.ndarray  # float64[n] arc length from the path start
    path_lane: np.ndarray  # int32[n]
    goal_kind: int
    goal_xy: np.ndarray  # float64[2] (zeros when there is no goal)
    goal_radius: float
    goal_road: int  # -1 unless a road goal
    goal_lane: int  # -1 for any lane of the goal road
    goal_s: float  # road goals are reached at or past this offset on the goal lane
    goal_gate: np.ndarray = None  # float64[6] road goals: the line across the road at goal_s
    """x, y of the goal point, unit lane direction dx, dy there, and the extent (lo, hi) of the
    goal lane (any lane: the whole road) along the left normal (-dy, dx) from the goal point. A
    step whose movement crosses this line forwards reaches the goal, however short the lane."""
    on_end: str = "remove"  # or "traffic": the vehicle goes back to traffic when the mission ends
    follow: str | None = None  # id of the vehicle this agent follows (its lead), None for none


def lane_pose_at(road_map: RoadMap, lane: int, s: float) -> tuple[np.ndarray, float]:
    """Position and heading on a lane centre line at arc length ``s`` (clamped to the lane)."""
    pts = road_map.lane_polyline(lane)
    a, b = road_map.lane_point_offsets[lane], road_map.lane_point_offsets[lane + 1]
    ps = road_map.point_s[a:b]
    s = float(np.clip(s, 0.0, ps[-1]))
    i = int(np.clip(np.searchsorted(ps, s, side="right") - 1, 0, len(ps) - 2))
    seg = pts[i + 1] - pts[i]
    seg_len = max(ps[i + 1] - ps[i], 1e-9)
    xy = pts[i] + seg * ((s - ps[i]) / seg_len)
    return xy, float(np.arctan2(seg[1], seg[0]))


def goal_line(road_map: RoadMap, lane: int, lanes: np.ndarray, s: float) -> np.ndarray:
    """float64[6]: the line across ``lanes`` (the goal lane, or all lanes of the goal road) at
    arc length ``s`` of ``lane``: goal point x, y, unit direction, and the lateral extent lo, hi
    of the lanes' outer edges along the left normal (see ``ResolvedMission.goal_gate``)."""
    xy, heading = lane_pose_at(road_map, lane, s)
    d = np.array([np.cos(heading), np.sin(heading)])
    normal = np.array([-d[1], d[0]])
    lo, hi = np.inf, -np.inf
    for other in np.asarray(lanes).tolist():
        # the same fraction of each lane's length: lanes of a curved road differ in length
        frac = s / max(float(road_map.lane_length[lane]), 1e-9)
        pos, _ = lane_pose_at(road_map, int(other), frac * float(road_map.lane_length[other]))
        u = float((pos - xy) @ normal)
        half = 0.5 * float(road_map.lane_width[other])
        lo, hi = min(lo, u - half), max(hi, u + half)
    return np.array([xy[0], xy[1], d[0], d[1], lo, hi])


def _lane_of(road_map: RoadMap, road_id: str, lane_index: int, where: str) -> int:
    try:
        road = road_map.road(road_id)
    except KeyError:
        raise MapError(f"{where}: map {road_map.source!r} has no road {road_id!r}") from None
    lanes = road_map.road_lanes(road)
    if not 0 <= lane_index < len(lanes):
        raise MapError(f"{where}: road {road_id!r} has {len(lanes)} lane(s) (0..{len(lanes) - 1}), got {lane_index}")
    return int(lanes[lane_index])


def _route_back(road_map: RoadMap, start: int, goal: int, where: str) -> np.ndarray:
    """Shortest route that leaves lane ``start`` forwards and comes back to lane ``goal`` of the
    same road (a goal behind the start); MapError naming ``where`` when no road leads back."""
    best, best_len = None, np.inf
    for via in road_map.successors(start):
        try:
            back = shortest_route(road_map, int(via), goal)
        except MapError:
            continue
        length = float(road_map.lane_length[back].sum())
        if length < best_len:
            best, best_len = back, length
    if best is None:
        road = road_map.road_ids[int(road_map.lane_road[start])]
        raise MapError(f"{where}: lies behind the start on road {road!r}, and no route leaves that road and "
                       "comes back to it, so the route cannot reach it; put the goal ahead of the start")  # fmt: skip
    return np.concatenate([[start], best]).astype(np.int32)


def _best_route(road_map: RoadMap, start: int, candidates: np.ndarray, where: str) -> np.ndarray:
    """Shortest route from ``start`` to any lane in ``candidates``."""
    best, best_len = None, np.inf
    errors = []
    for lane in candidates:
        try:
            route = shortest_route(road_map, start, int(lane))
        except MapError as err:
            errors.append(str(err))
            continue
        length = float(road_map.lane_length[route].sum())
        if length < best_len:
            best, best_len = route, length
    if best is None:
        raise MapError(f"{where}: no route: {'; '.join(errors)}")
    return best


def resolve_mission(road_map: RoadMap, agent_id: str, mission, where: str, traffic=None) -> ResolvedMission:
    """Resolve one agent's ``MissionSpec`` against the map; errors name ``where`` (the spec path).

    A mission that takes over a traffic trip starts where that trip departs (its first road, its
    depart lane when given as a number, else lane 0, and its depart position).
    """
    start, start_lane, start_xy, heading = _resolve_start(road_map, mission, where, traffic)
    route_parts, legs_from = _via_legs(road_map, mission, start_lane, where)
    goal = mission.goal
    fields = dict(
        goal_kind=GOAL_NONE,
        goal_xy=np.zeros(2),
        goal_radius=0.0,
        goal_road=-1,
        goal_lane=-1,
        goal_s=0.0,
        goal_gate=np.zeros(6),
    )
    if getattr(goal, "endless", False):
        tail = extend_route(road_map, legs_from, ENDLESS_ROUTE_LENGTH)
    elif getattr(goal, "position", None) is not None:
        tail, goal_fields = _position_goal(road_map, goal, start, start_lane, route_parts, legs_from, where)
        fields.update(goal_fields)
    else:
        tail, goal_fields = _road_goal(road_map, goal, start, start_lane, legs_from, where)
        fields.update(goal_fields)
    route = np.concatenate(route_parts + [tail if not route_parts else tail[1:]]).astype(np.int32)
    path = route_polyline(road_map, route, start_s=float(start.offset))
    end = len(path.s)
    if fields["goal_kind"] == GOAL_POSITION:  # the path ends abreast of the goal, not at its lane's end
        end = int(np.argmin(np.hypot(*(path.xy - fields["goal_xy"]).T))) + 1
    path_xy, path_heading, path_s, path_lane = path.xy[:end], path.heading[:end], path.s[:end], path.lane[:end]
    return ResolvedMission(
        agent_id=agent_id,
        start_lane=start_lane,
        start_xy=start_xy,
        start_heading=heading,
        start_speed=float(start.speed),
        route=route,
        path_xy=path_xy,
        path_heading=path_heading,
        path_s=path_s,
        path_lane=path_lane.astype(np.int32),
        **fields,
        on_end=getattr(mission, "on_end", "remove"),
        follow=getattr(mission, "follow", None),
    )


def _resolve_start(road_map: RoadMap, mission, where: str, traffic) -> tuple[Any, int, np.ndarray, float]:
    """The start spec (a taken-over trip's departure when the mission names one), its lane, position and heading."""
    start = mission.start
    take_over = getattr(start, "take_over", None)
    if take_over is not None:
        trips = {t.id: t for t in (traffic.trips if traffic is not None else [])}
        if take_over not in trips:
            raise MapError(f"{where}.start.take_over: no trip {take_over!r} in traffic.trips")
        trip = trips[take_over]
        lane = trip.depart_lane if isinstance(trip.depart_lane, int) else 0
        start = _TakeOverStart(trip.roads[0], lane, float(trip.depart_pos), 0.0, None)
    start_lane = _lane_of(road_map, start.road, start.lane, f"{where}.start")
    lane_len = float(road_map.lane_length[start_lane])
    if not 0.0 <= start.offset <= lane_len:
        raise MapError(
            f"{where}.start.offset: lane {road_map.lane_ids[start_lane]!r} is {lane_len:.1f} m long, got {start.offset}"
        )
    start_xy, heading = lane_pose_at(road_map, start_lane, start.offset)
    if getattr(start, "heading", None) is not None:
        heading = float(start.heading)
    return start, start_lane, start_xy, heading


def _via_legs(road_map: RoadMap, mission, start_lane: int, where: str) -> tuple[list[np.ndarray], int]:
    """Routes start lane -> each ``route_via`` road in turn (joined without repeating lanes), and the lane they end on."""
    legs_from = start_lane
    route_parts: list[np.ndarray] = []
    for k, via in enumerate(getattr(mission, "route_via", None) or []):
        try:
            via_road = road_map.road(via)
        except KeyError:
            raise MapError(f"{where}.route_via[{k}]: map has no road {via!r}") from None
        leg = _best_route(road_map, legs_from, road_map.road_lanes(via_road), f"{where}.route_via[{k}]")
        route_parts.append(leg if not route_parts else leg[1:])
        legs_from = int(leg[-1])
    return route_parts, legs_from


def _position_goal(
    road_map: RoadMap, goal, start, start_lane: int, route_parts: list, legs_from: int, where: str
) -> tuple[np.ndarray, dict]:
    """The last leg to a goal position, and the goal fields it sets; a goal behind the start loops back to it."""
    goal_xy = np.asarray(goal.position, dtype=np.float64)
    goal_radius = float(goal.radius)
    fields = dict(goal_kind=GOAL_POSITION, goal_xy=goal_xy, goal_radius=goal_radius)
    proj = project(road_map, goal_xy[None, :])
    if proj.lane[0] < 0:
        raise MapError(f"{where}.goal.position: {[round(float(v), 3) for v in goal_xy]} is not near any lane")
    goal_lane_of_xy = int(proj.lane[0])
    same_road = road_map.lane_road[goal_lane_of_xy] == road_map.lane_road[start_lane]
    if not route_parts and same_road and proj.s[0] + goal_radius < start.offset:
        # Behind the start on its road: the route must leave the road and come back to it.
        return _route_back(road_map, start_lane, goal_lane_of_xy, f"{where}.goal.position"), fields
    return _best_route(road_map, legs_from, np.array([goal_lane_of_xy]), f"{where}.goal"), fields


def _road_goal(road_map: RoadMap, goal, start, start_lane: int, legs_from: int, where: str) -> tuple[np.ndarray, dict]:
    """The last leg to a goal road (or one lane of it) at an offset, and the goal fields it sets (gate line too)."""
    try:
        goal_road = road_map.road(goal.road)
    except KeyError:
        raise MapError(f"{where}.goal.road: map has no road {goal.road!r}") from None
    fields = dict(goal_kind=GOAL_ROAD, goal_road=goal_road)
    lanes = road_map.road_lanes(goal_road)
    if goal.lane is not None:
        goal_lane = fields["goal_lane"] = _lane_of(road_map, goal.road, goal.lane, f"{where}.goal")
        lanes = np.array([goal_lane])
    goal_s = fields["goal_s"] = float(getattr(goal, "offset", None) or 0.0)
    if int(road_map.lane_road[start_lane]) == int(goal_road) and goal_s <= start.offset:
        # The goal test counts a vehicle on the goal road at or past goal_s as arrived: this
        # one would be at its goal from the first step, whatever route it then drove.
        raise MapError(
            f"{where}.goal: offset {goal_s:g} on road {goal.road!r} is not ahead of the start (offset "
            f"{start.offset:g} on the same road), so the route cannot reach it: the vehicle would count as "
            "arrived at its first step; put the goal ahead of the start or on another road"
        )
    tail = _best_route(road_map, legs_from, lanes, f"{where}.goal")
    fields["goal_xy"], _ = lane_pose_at(road_map, int(tail[-1]), goal_s)
    fields["goal_radius"] = float(road_map.lane_width[int(tail[-1])])
    fields["goal_gate"] = goal_line(road_map, int(tail[-1]), lanes, goal_s)
    return tail, fields


@dataclass
class _TakeOverStart:
    road: str
    lane: int
    offset: float
    speed: float
    heading: float | None


@dataclass
class MissionArrays:
    """All agents' route paths padded to one length, plus the parallel paths on adjacent lanes.

    ``paths[a, i, p]`` is point i of path p for agent a (x, y, heading), with p = 0 the route
    itself, 1 the lane to its left and 2 the lane to its right (the route shifted by the mean of
    both lanes' widths); ``path_valid`` masks padding and missing neighbour lanes. ``flat_paths``
    is the same memory as [A * M, P, 3], so one ``take`` gathers any agents' points.
    """

    paths: np.ndarray  # float64[A, M, 3, 3]
    path_valid: np.ndarray  # bool[A, M, 3]
    path_s: np.ndarray  # float64[A, M]
    path_len: np.ndarray  # int64[A] number of valid route points
    route_length: np.ndarray  # float64[A] arc length of the route path
    on_route_road: np.ndarray  # bool[A, R]
    goal_kind: np.ndarray  # int8[A]
    goal_xy: np.ndarray  # float64[A, 2]
    goal_radius: np.ndarray
    goal_road: np.ndarray  # int32[A]
    goal_lane: np.ndarray  # int32[A]
    goal_s: np.ndarray
    goal_gate: np.ndarray  # float64[A, 6] (see ResolvedMission.goal_gate)
    signal_via: np.ndarray  # int32[A, M] next signal-controlled junction lane on the route, -1 none
    signal_s: np.ndarray  # float64[A, M] route arc length of that signal's stop line

    @property
    def stride(self) -> int:
        return self.paths.shape[1]

    @property
    def flat_paths(self) -> np.ndarray:
        return self.paths.reshape(-1, 3, 3)

    @property
    def flat_valid(self) -> np.ndarray:
        return self.path_valid.reshape(-1, 3)


def stack_missions(road_map: RoadMap, missions: list[ResolvedMission]) -> MissionArrays:
    n_agents = len(missions)
    # One spare row past the longest path: clipping any index to the last row lands on padding.
    m = max((len(ms.path_s) for ms in missions), default=0) + 1
    paths = np.zeros((n_agents, m, 3, 3))
    valid = np.zeros((n_agents, m, 3), dtype=bool)
    path_s = np.zeros((n_agents, m))
    on_route_road = np.zeros((n_agents, len(road_map.road_ids)), dtype=bool)
    signal_via = np.full((n_agents, m), -1, dtype=np.int32)
    signal_s = np.zeros((n_agents, m))
    signalled = np.zeros(road_map.num_lanes, dtype=bool)
    signalled[road_map.conn_via[(road_map.conn_tls >= 0) & (road_map.conn_via >= 0)]] = True
    for a, ms in enumerate(missions):
        n = len(ms.path_s)
        paths[a, :n, 0, :2] = ms.path_xy
        paths[a, :n, 0, 2] = ms.path_heading
        valid[a, :n, 0] = True
        path_s[a, :n] = ms.path_s
        path_s[a, n:] = ms.path_s[-1]
        normal = np.stack([-np.sin(ms.path_heading), np.cos(ms.path_heading)], axis=1)
        own_width = road_map.lane_width[ms.path_lane]
        for p, side, sign in ((1, road_map.lane_left, 1.0), (2, road_map.lane_right, -1.0)):
            neighbour = side[ms.path_lane]
            shift = 0.5 * (own_width + road_map.lane_width[np.maximum(neighbour, 0)])
            paths[a, :n, p, :2] = ms.path_xy + sign * shift[:, None] * normal
            paths[a, :n, p, 2] = ms.path_heading
            valid[a, :n, p] = neighbour >= 0
        paths[a, n:] = paths[a, n - 1]  # padding repeats the last point (masked invalid)
        on_route_road[a] = route_roads(road_map, ms.route)
        # Points where the path enters a signalled junction lane: the stop line. Each point then
        # refers to the next such entry at or ahead of it.
        entries = np.flatnonzero(signalled[ms.path_lane[1:]] & (ms.path_lane[1:] != ms.path_lane[:-1])) + 1
        if entries.size:
            nxt_pos = np.searchsorted(entries, np.arange(n))
            ahead = nxt_pos < entries.size
            nxt = entries[np.minimum(nxt_pos, entries.size - 1)]
            signal_via[a, :n] = np.where(ahead, ms.path_lane[nxt], -1)
            signal_s[a, :n] = np.where(ahead, ms.path_s[nxt], 0.0)
    return MissionArrays(
        paths=paths,
        path_valid=valid,
        path_s=path_s,
        path_len=np.array([len(ms.path_s) for ms in missions], dtype=np.int64),
        route_length=np.array([ms.path_s[-1] for ms in missions]),
        on_route_road=on_route_road,
        goal_kind=np.array([ms.goal_kind for ms in missions], dtype=np.int8),
        goal_xy=np.array([ms.goal_xy for ms in missions]).reshape(-1, 2),
        goal_radius=np.array([ms.goal_radius for ms in missions]),
        goal_road=np.array([ms.goal_road for ms in missions], dtype=np.int32),
        goal_lane=np.array([ms.goal_lane for ms in missions], dtype=np.int32),
        goal_s=np.array([ms.goal_s for ms in missions]),
        goal_gate=np.array([ms.goal_gate if ms.goal_gate is not None else np.zeros(6) for ms in missions]).reshape(
            -1, 6
        ),
        signal_via=signal_via,
        signal_s=signal_s,
    )
