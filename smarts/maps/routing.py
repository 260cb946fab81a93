"""Shortest routes over the lane graph (successors plus lane changes).

Routes are lane sequences so a planner knows which lane to be in; the graph is built once per map
and kept on the map instance, and each query is one Dijkstra run in compiled scipy code.
"""

from __future__ import annotations

import numpy as np
from scipy.sparse import csr_matrix
from scipy.sparse.csgraph import dijkstra

from smarts.maps.errors import MapError, NoRouteError
from smarts.maps.projection import project
from smarts.maps.road_map import RoadMap

LANE_CHANGE_COST = 20.0
"""Route cost (metres) of one lane change. A lane change gains no distance, so a positive cost
keeps routes from weaving between lanes; 20 m (about 1.5 s at urban speed) makes a route prefer
staying in lane unless changing saves a comparable distance, and still lets routes change lanes
to reach a turn."""
_MIN_EDGE_COST = 1e-3  # csgraph treats explicit zeros as missing edges


def lane_graph(road_map: RoadMap, lane_change_cost: float = LANE_CHANGE_COST) -> csr_matrix:
    """Weighted lane graph: lane -> successor costs the lane's length, lane -> neighbour costs
    ``lane_change_cost``. Lane changes are only allowed outside junctions."""
    cache = road_map.__dict__.setdefault("_lane_graphs", {})
    graph = cache.get(lane_change_cost)
    if graph is not None:
        return graph
    n = road_map.num_lanes
    src = np.repeat(np.arange(n), np.diff(road_map.succ_offsets))
    dst = road_map.succ.astype(np.int64)
    cost = np.maximum(road_map.lane_length[src], _MIN_EDGE_COST)
    rows, cols, weights = [src], [dst], [cost]
    for side in (road_map.lane_left, road_map.lane_right):
        ok = (side >= 0) & ~road_map.lane_internal
        rows.append(np.flatnonzero(ok))
        cols.append(side[ok].astype(np.int64))
        weights.append(np.full(int(ok.sum()), max(lane_change_cost, _MIN_EDGE_COST)))
    # Keep the cheapest of duplicate edges (csr_matrix would add them up).
    r, c, w = np.concatenate(rows), np.concatenate(cols), np.concatenate(weights)
    order = np.lexsort((w, c, r))
    r, c, w = r[order], c[order], w[order]
    first = np.ones(len(r), dtype=bool)
    first[1:] = (r[1:] != r[:-1]) | (c[1:] != c[:-1])
    graph = csr_matrix((w[first], (r[first], c[first])), shape=(n, n))
    cache[lane_change_cost] = graph
    return graph


def shortest_route(
    road_map: RoadMap,
    start_lane: int,
    end_lane: int,
    lane_change_cost: float = LANE_CHANGE_COST,
) -> np.ndarray:
    """Cheapest lane sequence from ``start_lane`` to ``end_lane`` (both included).

    Consecutive entries are successors or same-road neighbours (a lane change).
    """
    n = road_map.num_lanes
    for name, lane in (("start", start_lane), ("end", end_lane)):
        if not 0 <= int(lane) < n:
            raise MapError(f"{road_map.source}: {name} lane {lane} is not a lane index (0..{n - 1})")
    if start_lane == end_lane:
        return np.array([start_lane], dtype=np.int32)
    graph = lane_graph(road_map, lane_change_cost)
    dist, pred = dijkstra(graph, indices=int(start_lane), return_predecessors=True)
    if not np.isfinite(dist[end_lane]):
        raise NoRouteError(
            f"{road_map.source}: no route from lane {road_map.lane_ids[start_lane]!r} "
            f"to lane {road_map.lane_ids[end_lane]!r}"
        )
    route = [int(end_lane)]
    while route[-1] != start_lane:
        route.append(int(pred[route[-1]]))
    return np.array(route[::-1], dtype=np.int32)


def route_between(
    road_map: RoadMap,
    start_xy: np.ndarray,
    goal_xy: np.ndarray,
    start_heading: float | None = None,
    lane_change_cost: float = LANE_CHANGE_COST,
) -> np.ndarray:
    """Lane route from the lane under ``start_xy`` to the lane under ``goal_xy``.

    When both lie on the same lane but the goal is behind the start, the route loops around
    (leaving the lane and coming back) instead of returning the single lane.
    """
    heading = None if start_heading is None else np.array([start_heading], dtype=np.float64)
    start = project(road_map, np.asarray(start_xy, dtype=np.float64).reshape(1, 2), heading)
    goal = project(road_map, np.asarray(goal_xy, dtype=np.float64).reshape(1, 2))
    for name, proj, xy in (("start", start, start_xy), ("goal", goal, goal_xy)):
        if proj.lane[0] < 0:
            raise MapError(f"{road_map.source}: {name} position {tuple(xy)} is not near any lane")
    a, b = int(start.lane[0]), int(goal.lane[0])
    if a != b or goal.s[0] >= start.s[0]:
        return shortest_route(road_map, a, b, lane_change_cost)
    # Goal behind the start on the same lane: drive off the end of the lane and come back.
    exits = road_map.successors(a)
    if len(exits) == 0:
        raise NoRouteError(
            f"{road_map.source}: the goal is behind the start on lane {road_map.lane_ids[a]!r}, which is a dead end"
        )
    graph = lane_graph(road_map, lane_change_cost)
    dist = dijkstra(graph, indices=exits.astype(np.int64))[:, b]
    if not np.isfinite(dist).any():
        raise NoRouteError(f"{road_map.source}: no route leaves lane {road_map.lane_ids[a]!r} and returns to it")
    via = int(exits[int(np.argmin(dist))])
    return np.concatenate([[a], shortest_route(road_map, via, b, lane_change_cost)]).astype(np.int32)


def junction_links(road_map: RoadMap) -> tuple[list[frozenset[int]], list[frozenset[int]]]:
    """For each lane, the non-junction roads reachable backwards / forwards through junction
    lanes only (empty for lanes outside junctions). Lets route checks treat every path through a
    junction between two route roads as on the route."""
    cached = road_map.__dict__.get("_junction_links")
    if cached is not None:
        return cached
    n = road_map.num_lanes
    internal = road_map.lane_internal
    entries: list[frozenset[int]] = [frozenset()] * n
    exits: list[frozenset[int]] = [frozenset()] * n
    for lane in np.flatnonzero(internal):
        for table, step in ((entries, road_map.predecessors), (exits, road_map.successors)):
            found: set[int] = set()
            seen = {int(lane)}
            stack = [int(lane)]
            while stack:
                for nxt in step(stack.pop()):
                    nxt = int(nxt)
                    if nxt in seen:
                        continue
                    seen.add(nxt)
                    if internal[nxt]:
                        stack.append(nxt)
                    else:
                        found.add(int(road_map.lane_road[nxt]))
            table[lane] = frozenset(found)
    road_map.__dict__["_junction_links"] = (entries, exits)
    return entries, exits


def route_roads(road_map: RoadMap, lane_route: np.ndarray) -> np.ndarray:
    """Boolean mask over roads that count as "on the route".

    The roads of the route's lanes, plus every junction road that connects one route road to
    another (a vehicle may cross a junction on a parallel turning lane and still be on route).
    Per step, ``mask[road_map.lane_road[lane]]`` tells whether a vehicle is on its route.
    """
    mask = np.zeros(len(road_map.road_ids), dtype=bool)
    lanes = np.asarray(lane_route, dtype=np.int64)
    if len(lanes) == 0:
        return mask
    mask[road_map.lane_road[lanes]] = True
    entries, exits = junction_links(road_map)
    route_set = {int(r) for r in road_map.lane_road[lanes]}
    for lane in np.flatnonzero(road_map.lane_internal):
        if entries[lane] & route_set and exits[lane] & route_set:
            mask[road_map.lane_road[lane]] = True
    return mask
