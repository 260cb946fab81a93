"""Generated traffic for a density level: flows from every entry road to every exit road it reaches.

Both traffic engines turn ``traffic.density`` into the same list of ``FlowSpec`` with
``density_flows``, so a scenario looks alike whichever engine runs it. The road-level graph used
for that (which road leads to which through a junction) is also what the built-in engine routes on.
"""

from __future__ import annotations

import math

import numpy as np

from smarts.core.errors import ScenarioError
from smarts.core.spec.traffic import DENSITY_LEVELS, DENSITY_RATES, FlowSpec, TrafficSpec
from smarts.maps import RoadMap

DENSITY_FLOW_END = 86400.0
"""Generated flows run for a day of simulated time, i.e. for any episode."""
TURNAROUND_ANGLE = math.radians(150.0)
"""A link whose heading turns by more than this is a U-turn; generated traffic does not make them."""


def lane_exits(road_map: RoadMap) -> list[list[tuple[tuple[int, ...], int]]]:
    """For each lane, the ways out of it: (junction lanes passed, first non-junction lane reached).

    A lane whose successor is a normal lane yields ``((), that lane)``. Cached on the map.
    """
    cached = road_map.__dict__.get("_lane_exits")
    if cached is not None:
        return cached
    internal = road_map.lane_internal
    out: list[list[tuple[tuple[int, ...], int]]] = []
    for lane in range(road_map.num_lanes):
        found: list[tuple[tuple[int, ...], int]] = []
        stack: list[tuple[tuple[int, ...], int]] = [((), int(n)) for n in road_map.successors(lane)]
        while stack:
            path, nxt = stack.pop(0)
            if not internal[nxt]:
                found.append((path, nxt))
                continue
            if nxt in path or len(path) > 16:  # guards against cycles of junction lanes
                continue
            stack.extend((path + (nxt,), int(n)) for n in road_map.successors(nxt))
        out.append(found)
    road_map.__dict__["_lane_exits"] = out
    return out


def _end_heading(road_map: RoadMap, lane: int, at_end: bool) -> float:
    pts = road_map.lane_polyline(lane)
    d = pts[-1] - pts[-2] if at_end else pts[1] - pts[0]
    return math.atan2(d[1], d[0])


def road_links(road_map: RoadMap) -> dict[int, dict[int, bool]]:
    """Road -> {next road: whether every way there is a U-turn}, over non-junction roads."""
    cached = road_map.__dict__.get("_road_links")
    if cached is not None:
        return cached
    links: dict[int, dict[int, bool]] = {}
    exits = lane_exits(road_map)
    for lane in np.flatnonzero(~road_map.lane_internal):
        lane = int(lane)
        road = int(road_map.lane_road[lane])
        mine = links.setdefault(road, {})
        h0 = _end_heading(road_map, lane, True)
        for _, target in exits[lane]:
            turn = abs(math.remainder(_end_heading(road_map, target, False) - h0, 2 * math.pi))
            nxt = int(road_map.lane_road[target])
            mine[nxt] = mine.get(nxt, True) and turn > TURNAROUND_ANGLE
    road_map.__dict__["_road_links"] = links
    return links


def entry_roads(road_map: RoadMap) -> list[int]:
    """Non-junction roads no lane leads into (where traffic enters the map)."""
    has_pred = np.diff(road_map.pred_offsets) > 0
    roads = []
    for road in road_map.own_roads():
        lanes = road_map.road_lanes(road)
        if len(lanes) and not road_map.lane_internal[lanes].any() and not has_pred[lanes].any():
            roads.append(road)
    return roads


def exit_roads(road_map: RoadMap) -> list[int]:
    """Non-junction roads that lead nowhere (where traffic leaves the map)."""
    has_succ = np.diff(road_map.succ_offsets) > 0
    roads = []
    for road in road_map.own_roads():
        lanes = road_map.road_lanes(road)
        if len(lanes) and not road_map.lane_internal[lanes].any() and not has_succ[lanes].any():
            roads.append(road)
    return roads


def reachable_roads(road_map: RoadMap, start: int, u_turns: bool = False) -> set[int]:
    """Roads reachable from road ``start`` (itself included), optionally without U-turns."""
    links = road_links(road_map)
    seen = {start}
    stack = [start]
    while stack:
        for nxt, u_turn in links.get(stack.pop(), {}).items():
            if nxt not in seen and (u_turns or not u_turn):
                seen.add(nxt)
                stack.append(nxt)
    return seen


def density_flows(traffic: TrafficSpec, road_map: RoadMap) -> list[FlowSpec]:
    """Flows for ``traffic.density``: DENSITY_RATES[level] vehicles per hour enter on each entry
    road, shared evenly among the exit roads it reaches without a U-turn.

    Departures are random (a probability per second), so each seed gives a different but
    reproducible stream. Flow ids are ``density.<entry>.<exit>``; vehicles use type ``car``, the
    best lane and the highest safe speed. Level ``none`` gives no flows.
    """
    level = traffic.density
    if level not in DENSITY_RATES:
        raise ScenarioError(f"traffic.density: expected one of {list(DENSITY_LEVELS)}, got {level!r}")
    rate = DENSITY_RATES[level]
    if rate <= 0:
        return []
    exits = set(exit_roads(road_map))
    flows: list[FlowSpec] = []
    for entry in entry_roads(road_map):
        # An entry road that is also an exit (a lone road) sends traffic along itself.
        targets = sorted(r for r in reachable_roads(road_map, entry) if r in exits)
        for target in targets:
            a, b = road_map.road_ids[entry], road_map.road_ids[target]
            route = [a] if a == b else [a, b]
            flows.append(
                FlowSpec(
                    id=f"density.{a}.{b}",
                    route=route,
                    probability=rate / len(targets) / 3600.0,
                    end=DENSITY_FLOW_END,
                    depart_lane="best",
                    depart_speed="max",
                )
            )
    return flows
