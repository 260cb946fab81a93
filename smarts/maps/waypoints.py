"""Paths of lane-centre points: dense route paths and per-lane waypoint paths.

``route_polyline`` turns a lane route into one resampled path (what planners track and what trip
progress is measured along). ``waypoint_paths`` is the general, SMARTS-style query: one path per
lane of the current road, branching at junctions; it is convenient rather than per-step fast.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np

from smarts.maps.errors import MapError
from smarts.maps.projection import project
from smarts.maps.road_map import RoadMap
from smarts.maps.routing import junction_links

LANE_CHANGE_LENGTH = 10.0
"""Metres along the lane over which a route path blends from one lane to its neighbour."""
_TRANSITION_STEP = 0.5  # metres between raw samples of a lane-change blend


class RoutePath(NamedTuple):
    """A dense path along a route, resampled to even spacing."""

    xy: np.ndarray  # float64[n, 2]
    heading: np.ndarray  # float64[n]
    s: np.ndarray  # float64[n] cumulative distance along the path, s[0] = 0
    lane: np.ndarray  # int32[n] lane the point belongs to


def lane_points_at(road_map: RoadMap, lane: int, s: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Centre-line positions ``xy[k, 2]`` and headings ``[k]`` of a lane at arc lengths ``s``."""
    a, b = int(road_map.lane_point_offsets[lane]), int(road_map.lane_point_offsets[lane + 1])
    ps = road_map.point_s[a:b]
    pts = road_map.points[a:b]
    s = np.asarray(s, dtype=np.float64)
    xy = np.stack([np.interp(s, ps, pts[:, 0]), np.interp(s, ps, pts[:, 1])], axis=-1)
    local = np.clip(np.searchsorted(ps, s, side="right") - 1, 0, b - a - 2)
    return xy, road_map.seg_heading[a - lane + local]


def _lane_piece(road_map: RoadMap, lane: int, s0: float, s1: float) -> np.ndarray:
    """Raw polyline of a lane between arc lengths s0 <= s1 (its own vertices in between)."""
    a, b = int(road_map.lane_point_offsets[lane]), int(road_map.lane_point_offsets[lane + 1])
    ps = road_map.point_s[a:b]
    inner = (ps > s0) & (ps < s1)
    ends, _ = lane_points_at(road_map, lane, np.array([s0, s1]))
    return np.concatenate([ends[:1], road_map.points[a:b][inner], ends[1:]])


def _neighbour_of(road_map: RoadMap, a: int, b: int) -> bool:
    return b == road_map.lane_left[a] or b == road_map.lane_right[a]


def route_polyline(
    road_map: RoadMap,
    lane_route: np.ndarray,
    start_s: float = 0.0,
    spacing: float = 1.0,
    lane_change_length: float = LANE_CHANGE_LENGTH,
) -> RoutePath:
    """Resample a lane route into an evenly spaced path starting at ``start_s`` on its first lane.

    A lane change (consecutive lanes that are neighbours) starts where the path is on the current
    lane and blends sideways over ``lane_change_length`` metres (a smoothstep), so the path has no
    lateral jump.
    """
    route = [int(x) for x in np.asarray(lane_route).reshape(-1)]
    if not route:
        raise MapError(f"{road_map.source}: an empty lane route has no path")
    if spacing <= 0:
        raise MapError(f"{road_map.source}: path spacing must be positive, got {spacing}")
    pieces: list[np.ndarray] = []
    labels: list[np.ndarray] = []
    cur = route[0]
    s_cur = float(np.clip(start_s, 0.0, road_map.lane_length[cur]))
    for nxt in route[1:]:
        length = float(road_map.lane_length[cur])
        if nxt in road_map.successors(cur):
            piece = _lane_piece(road_map, cur, s_cur, length)
            pieces.append(piece)
            labels.append(np.full(len(piece), cur))
            cur, s_cur = nxt, 0.0
        elif _neighbour_of(road_map, cur, nxt):
            change = min(lane_change_length, length - s_cur)
            ratio = road_map.lane_length[nxt] / length if length > 0 else 1.0
            k = max(2, math.ceil(change / _TRANSITION_STEP) + 1)
            s = s_cur + np.linspace(0.0, change, k)
            w = np.linspace(0.0, 1.0, k) if change > 0 else np.ones(k)
            w = w * w * (3.0 - 2.0 * w)
            here, _ = lane_points_at(road_map, cur, s)
            there, _ = lane_points_at(road_map, nxt, s * ratio)
            pieces.append((1.0 - w)[:, None] * here + w[:, None] * there)
            labels.append(np.where(w < 0.5, cur, nxt))
            cur, s_cur = nxt, float(min((s_cur + change) * ratio, road_map.lane_length[nxt]))
        else:
            raise MapError(
                f"{road_map.source}: lane {road_map.lane_ids[nxt]!r} neither follows nor "
                f"neighbours lane {road_map.lane_ids[cur]!r} in the route"
            )
    last = _lane_piece(road_map, cur, s_cur, float(road_map.lane_length[cur]))
    pieces.append(last)
    labels.append(np.full(len(last), cur))

    raw = np.concatenate(pieces)
    raw_lane = np.concatenate(labels)
    keep = np.ones(len(raw), dtype=bool)
    keep[1:] = np.hypot(*np.diff(raw, axis=0).T) > 1e-9
    raw, raw_lane = raw[keep], raw_lane[keep]
    if len(raw) < 2:
        _, heading = lane_points_at(road_map, cur, np.array([s_cur]))
        return RoutePath(raw[:1].copy(), heading, np.zeros(1), np.array([cur], dtype=np.int32))

    seg = np.diff(raw, axis=0)
    raw_s = np.concatenate([[0.0], np.cumsum(np.hypot(seg[:, 0], seg[:, 1]))])
    total = raw_s[-1]
    n = max(1, math.ceil(total / spacing - 1e-9))
    s = np.minimum(np.arange(n + 1) * spacing, total)
    xy = np.stack([np.interp(s, raw_s, raw[:, 0]), np.interp(s, raw_s, raw[:, 1])], axis=1)
    idx = np.clip(np.searchsorted(raw_s, s, side="right") - 1, 0, len(seg) - 1)
    heading = np.arctan2(seg[idx, 1], seg[idx, 0])
    lane = raw_lane[idx + 1].astype(np.int32)
    return RoutePath(xy, heading, s, lane)


def extend_route(road_map: RoadMap, lane: int, min_length: float) -> np.ndarray:
    """Endless-mission route: from ``lane`` follow the straightest successor until the lanes
    add up to ``min_length`` metres (the first lane counts fully) or a dead end is reached."""
    route = [int(lane)]
    total = float(road_map.lane_length[lane])
    limit = road_map.num_lanes * 4 + 16  # guards against cycles of zero-length lanes
    while total < min_length and len(route) < limit:
        cur = route[-1]
        options = road_map.successors(cur)
        if len(options) == 0:
            break
        end_heading = lane_points_at(road_map, cur, np.array([road_map.lane_length[cur]]))[1][0]
        turns = []
        for nxt in options:
            h = lane_points_at(road_map, int(nxt), np.array([road_map.lane_length[nxt]]))[1][0]
            turns.append(abs(math.remainder(h - end_heading, 2 * math.pi)))
        best = int(options[int(np.argmin(turns))])
        route.append(best)
        total += float(road_map.lane_length[best])
    return np.array(route, dtype=np.int32)


def waypoint_paths(
    road_map: RoadMap,
    xy: np.ndarray,
    heading: float,
    lookahead: int = 20,
    route: np.ndarray | None = None,
    spacing: float = 1.0,
) -> list[np.ndarray]:
    """Lane-centre paths ahead of a position, each float64[k, 4] of (x, y, heading, lane).

    One path per lane of the road the position is on (rightmost first), starting abreast of the
    position and holding up to ``lookahead + 1`` points ``spacing`` apart. Without a route, a path
    splits into one path per successor at a junction; with a route (a lane sequence) a path only
    continues onto lanes that lead along the route's roads and ends where the route does.
    """
    proj = project(
        road_map,
        np.asarray(xy, dtype=np.float64).reshape(1, 2),
        np.array([heading], dtype=np.float64),
    )
    here = int(proj.lane[0])
    if here < 0:
        return []
    plan = _RoutePlan(road_map, route) if route is not None and len(route) else None
    paths: list[np.ndarray] = []
    for lane in road_map.road_lanes(int(road_map.lane_road[here])):
        lane = int(lane)
        ratio = road_map.lane_length[lane] / max(road_map.lane_length[here], 1e-9)
        s0 = float(np.clip(proj.s[0] * ratio, 0.0, road_map.lane_length[lane]))
        step = plan.start_step(lane) if plan is not None else None
        paths.extend(_grow(road_map, lane, s0, lookahead + 1, spacing, plan, step))
    return paths


def _grow(
    road_map: RoadMap,
    lane: int,
    s0: float,
    count: int,
    spacing: float,
    plan: "_RoutePlan | None",
    step: int | None,
) -> list[np.ndarray]:
    """Paths of ``count`` points starting at ``s0`` on ``lane``, continuing onto successors."""
    length = float(road_map.lane_length[lane])
    k = min(count, int(math.floor((length - s0) / spacing + 1e-9)) + 1) if s0 <= length else 0
    s = s0 + np.arange(k) * spacing
    xy, heading = lane_points_at(road_map, lane, s)
    head = np.column_stack([xy, heading, np.full(k, float(lane))])
    remaining = count - k
    if remaining == 0:
        return [head]
    if plan is None or step is None:
        options = [(int(n), None) for n in road_map.successors(lane)]
    else:
        options = plan.next_lanes(lane, step)
    if not options:
        return [head]
    next_s = s0 + k * spacing - length  # keep the spacing continuous across the lane joint
    tails: list[np.ndarray] = []
    for nxt, nxt_step in options:
        tails.extend(_grow(road_map, nxt, next_s, remaining, spacing, plan, nxt_step))
    return [np.concatenate([head, tail]) for tail in tails]


class _RoutePlan:
    """Which successor lanes keep a waypoint path on a route's sequence of (non-junction) roads."""

    def __init__(self, road_map: RoadMap, route: np.ndarray) -> None:
        self.map = road_map
        lanes = [int(x) for x in np.asarray(route).reshape(-1)]
        self.route_lanes = set(lanes)
        roads: list[int] = []
        for lane in lanes:
            if road_map.lane_internal[lane]:
                continue
            road = int(road_map.lane_road[lane])
            if not roads or roads[-1] != road:
                roads.append(road)
        self.roads = roads
        self.entries, self.exits = junction_links(road_map)

    def start_step(self, lane: int) -> int | None:
        """Index in the route's roads of the road the lane is on (or has just left)."""
        m = self.map
        if not m.lane_internal[lane]:
            road = int(m.lane_road[lane])
            return self.roads.index(road) if road in self.roads else None
        for i in range(len(self.roads) - 1):
            if self.roads[i] in self.entries[lane] and self.roads[i + 1] in self.exits[lane]:
                return i
        return None

    def next_lanes(self, lane: int, step: int) -> list[tuple[int, int]]:
        if step + 1 >= len(self.roads):
            return []
        target = self.roads[step + 1]
        m = self.map
        options: list[tuple[int, int]] = []
        for nxt in m.successors(lane):
            nxt = int(nxt)
            if m.lane_internal[nxt]:
                if target in self.exits[nxt]:
                    options.append((nxt, step))
            elif int(m.lane_road[nxt]) == target:
                options.append((nxt, step + 1))
        # One path per starting lane: prefer the lane the route itself takes.
        options.sort(key=lambda item: (item[0] not in self.route_lanes, item[0]))
        return options[:1]
