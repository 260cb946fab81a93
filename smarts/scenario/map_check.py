"""Checking a scenario against its compiled map, with every problem naming its field.

Each agent's mission: the start lies on a lane of a normal road (its offset on that lane, its speed
within the lane's speed limit times ``START_SPEED_MARGIN`` and, when the caller gives the vehicle's
``ReachLimits``, within what the action space can drive), the goal lies on the map, and the map's
routing finds a route from the start through each ``route_via`` road to the goal. Each traffic flow
and trip: its roads exist outside junctions, each road of its route (or its destination) can be
reached from the one before, its depart lane, position and speed fit its first road. Pedestrian
flows: their roads exist.

All problems are collected and reported at once, one line each (``file: agents[1].mission.goal: no
route from road 'a' lane 0 to road 'b'``).
"""

from __future__ import annotations

import difflib
from pathlib import Path
from typing import Any

import numpy as np

from smarts.core.errors import MapError, ScenarioError
from smarts.core.spec.scenario import ScenarioSpec
from smarts.core.spec.traffic import TrafficSpec

START_SPEED_MARGIN = 1.5
"""A start (or traffic depart) speed may be up to this many times its lane's speed limit: drivers
speed, but a start at twice the limit is a unit mistake or a scenario no policy can be fair in."""
REACH_LIMITED_SPACES = ("relative_target_pose", "target_pose", "lane")
"""Action spaces whose vehicles obey ``smarts.dynamics.limits.ReachLimits`` (the pose spaces and
the lane controller): a start above its ``max_speed`` would only brake at once."""

Problem = tuple[str, str]
"""(dotted field, message)."""


def check_map(spec: ScenarioSpec, road_map: Any, limits: Any = None) -> None:
    """Raise a ``ScenarioError`` listing every problem of ``spec`` on ``road_map`` (see
    :func:`map_problems`), one line each: ``source: field: message``.

    ``road_map`` needs ``road_index_of``, ``road_lanes(road)`` and ``lane_length`` (and uses the
    speed limits, lane graph, ``lane_internal`` and ``bounds`` when present), as on
    :class:`smarts.maps.road_map.RoadMap`. ``limits`` (``ReachLimits``) also bounds the start speeds
    of agents whose action space obeys them."""
    problems = map_problems(spec, road_map, limits)
    if problems:
        raise ScenarioError("\n".join(f"{spec.source}: {where}: {message}" for where, message in problems))


def map_problems(spec: ScenarioSpec, road_map: Any, limits: Any = None) -> list[Problem]:
    """Every problem of the missions and traffic of ``spec`` on ``road_map``, as (field, message).

    ``road_map`` needs ``road_index_of``, ``road_lanes(road)`` and ``lane_length``; the speed,
    route and goal-position checks run when it also has ``lane_speed_limit``, the lane graph
    (``succ_offsets`` ...) and the segment index, as a :class:`smarts.maps.road_map.RoadMap` does.
    ``limits`` (``ReachLimits``) bounds the start speed of agents whose action space obeys them;
    None skips that check (the simulation may be built with other limits).
    """
    checker = _MapChecker(road_map, limits)
    trips = {t.id: t for t in (spec.traffic.trips if spec.traffic is not None else [])}
    for i, agent in enumerate(spec.agents):
        checker.mission(f"agents[{i}]", agent, trips)
    if spec.traffic is not None:
        checker.traffic(spec.traffic)
    return checker.problems


class _MapChecker:
    """Checks scenario references against a compiled map, collecting (field, message) problems."""

    def __init__(self, road_map: Any, limits: Any) -> None:
        self.map = road_map
        self.limits = limits
        self.map_name = Path(str(getattr(road_map, "source", "") or "map")).name
        self.problems: list[Problem] = []
        n = len(road_map.lane_length)
        self.has_speed_limits = len(getattr(road_map, "lane_speed_limit", ())) == n
        self.has_graph = len(getattr(road_map, "succ_offsets", ())) == n + 1
        self.has_index = len(getattr(road_map, "seg_lane", ())) > 0

    def add(self, path: str, message: str) -> None:
        self.problems.append((path, message))

    # ------------------------------------------------------------------ roads and lanes
    def road(self, path: str, road: str) -> np.ndarray | None:
        """The lanes of a normal road (rightmost first), or None after reporting a problem."""
        index = self.map.road_index_of.get(road)
        if index is None:
            normal = sorted(r for r in self.map.road_index_of if not r.startswith(":"))
            hint = difflib.get_close_matches(road, normal, n=1)
            suggestion = f" (did you mean {hint[0]!r}?)" if hint else ""
            shown = ", ".join(normal[:30]) + (", ..." if len(normal) > 30 else "")
            self.add(path, f"map {self.map_name!r} has no road {road!r}{suggestion}; roads: {shown}")
            return None
        lanes = self.map.road_lanes(index)
        internal = getattr(self.map, "lane_internal", None)
        if road.startswith(":") or (internal is not None and len(lanes) and bool(internal[lanes[0]])):
            self.add(path, f"road {road!r} lies inside a junction; name a normal road")
            return None
        return lanes

    def lane_offset(
        self,
        road: str,
        lanes: Any,
        lane: int | None,
        offset: float | None,
        lane_path: str,
        offset_path: str,
        offset_name: str,
    ) -> bool:
        """The lane exists on the road and the offset lies on it (on every lane when None)."""
        n = len(lanes)
        if lane is not None and lane >= n:
            self.add(lane_path, f"road {road!r} has {n} lanes (0..{n - 1}), got {lane}")
            return False
        if offset is None:
            return True
        candidates = [lanes[lane]] if lane is not None else list(lanes)
        length = min(float(self.map.lane_length[i]) for i in candidates)
        if offset > length:
            which = f"lane {lane} of road {road!r}" if lane is not None else f"road {road!r}"
            self.add(offset_path, f"{which} is {length:.1f} m long, got {offset_name} {offset:g}")
            return False
        return True

    def road_lane(self, path: str, road: str, lane: int | None, offset: float | None) -> int | None:
        """The lane (a map index) named by road, lane and offset; None after a problem, or when
        ``lane`` is None (any lane of the road)."""
        lanes = self.road(f"{path}.road", road)
        if lanes is None:
            return None
        if not self.lane_offset(road, lanes, lane, offset, f"{path}.lane", f"{path}.offset", "offset"):
            return None
        return None if lane is None else int(lanes[lane])

    def lane_name(self, lane: int) -> str:
        """``road 'x' lane n`` with the lane counted as a scenario counts it (0 = rightmost)."""
        road = int(self.map.lane_road[lane])
        position = list(self.map.road_lanes(road)).index(lane)
        return f"road {self.map.road_ids[road]!r} lane {position}"

    # ------------------------------------------------------------------ speeds
    def speed(self, path: str, lanes: Any, speed: float, what: str) -> None:
        """``speed`` is within the lanes' speed limit times the margin."""
        if not self.has_speed_limits or not len(lanes):
            return
        limit = float(np.max(self.map.lane_speed_limit[np.asarray(lanes)]))
        if limit > 0 and speed > limit * START_SPEED_MARGIN:
            self.add(
                path,
                f"{what} has a speed limit of {limit:.2f} m/s; expected at most "
                f"{START_SPEED_MARGIN:g} times that ({limit * START_SPEED_MARGIN:.2f} m/s), got {speed:g}",
            )

    # ------------------------------------------------------------------ missions
    def mission(self, where: str, agent: Any, trips: dict[str, Any]) -> None:
        mission = agent.mission
        path = f"{where}.mission"
        start = mission.start
        if start.take_over is None:  # a taken-over vehicle starts where its trip departs
            start_lane = self.road_lane(f"{path}.start", start.road, start.lane, start.offset)
            if start_lane is not None:
                lane_name = f"lane {start.lane} of road {start.road!r}"
                self.speed(f"{path}.start.speed", [start_lane], start.speed, lane_name)
            if (
                self.limits is not None
                and agent.action_space in REACH_LIMITED_SPACES
                and start.speed > self.limits.max_speed
            ):
                self.add(
                    f"{path}.start.speed",
                    f"the {agent.action_space} action space drives at most {self.limits.max_speed:g} m/s "
                    f"(ReachLimits.max_speed), got {start.speed:g}",
                )
        else:
            start_lane = self.take_over_lane(trips.get(start.take_over))
        goal = mission.goal
        goal_ok = True
        if goal.kind == "road":
            lanes = self.road(f"{path}.goal.road", goal.road)
            goal_ok = lanes is not None and self.lane_offset(
                goal.road, lanes, goal.lane, goal.offset, f"{path}.goal.lane", f"{path}.goal.offset", "offset"
            )
        elif goal.kind == "position":
            goal_ok = self.position(f"{path}.goal.position", goal.position, goal.radius)
        via_ok = [self.road(f"{path}.route_via[{j}]", road) is not None for j, road in enumerate(mission.route_via)]
        if start_lane is not None and goal_ok and all(via_ok) and self.has_graph:
            self.route(path, start_lane, mission)

    def take_over_lane(self, trip: Any) -> int | None:
        """Where a taken-over trip's vehicle starts (as ``smarts.core.missions`` places it); None
        when the trip or its first road is unusable (reported with the traffic)."""
        if trip is None:
            return None
        index = self.map.road_index_of.get(trip.roads[0])
        if index is None:
            return None
        lanes = self.map.road_lanes(index)
        lane = trip.depart_lane if isinstance(trip.depart_lane, int) else 0
        return int(lanes[lane]) if 0 <= lane < len(lanes) else None

    def route(self, path: str, start_lane: int, mission: Any) -> None:
        """A route from the start through each ``route_via`` road to the goal, leg by leg, each
        leg ending on its target's lane that the shortest route reaches (as the simulation plans
        it, ``smarts.core.missions``)."""
        current = start_lane
        for j, road in enumerate(mission.route_via):
            lanes = self.map.road_lanes(self.map.road_index_of[road])
            leg = self.best_route(current, lanes)
            if leg is None:
                self.add(f"{path}.route_via[{j}]", f"no route from {self.lane_name(current)} to road {road!r}")
                return
            current = int(leg[-1])
        goal = mission.goal
        if goal.kind == "road":
            lanes = self.map.road_lanes(self.map.road_index_of[goal.road])
            target = f"road {goal.road!r}"
            if goal.lane is not None:
                lanes = lanes[[goal.lane]]
                target += f" lane {goal.lane}"
        elif goal.kind == "position":
            if not self.has_index:
                return
            from smarts.maps import project

            proj = project(self.map, np.asarray(goal.position, dtype=np.float64).reshape(1, 2))
            if proj.lane[0] < 0:
                x, y = goal.position
                self.add(f"{path}.goal.position", f"({x:g}, {y:g}) is not near any lane")
                return
            lanes = np.array([int(proj.lane[0])])
            x, y = goal.position
            target = f"the goal position ({x:g}, {y:g}) on {self.lane_name(int(proj.lane[0]))}"
        else:
            return  # endless: the route is extended as far as the roads go
        if self.best_route(current, lanes) is None:
            self.add(f"{path}.goal", f"no route from {self.lane_name(current)} to {target}")

    def best_route(self, start: int, candidates: Any) -> np.ndarray | None:
        """Shortest route from ``start`` to the nearest reachable lane of ``candidates``."""
        from smarts.maps import shortest_route

        best, best_len = None, np.inf
        for lane in candidates:
            try:
                route = shortest_route(self.map, int(start), int(lane))
            except MapError:
                continue
            length = float(self.map.lane_length[route].sum())
            if length < best_len:
                best, best_len = route, length
        return best

    def reaches(self, road_a: int, road_b: int) -> bool:
        """Whether some lane of ``road_a`` leads to some lane of ``road_b`` in the lane graph."""
        from scipy.sparse.csgraph import dijkstra

        from smarts.maps.routing import lane_graph

        lanes_a, lanes_b = self.map.road_lanes(road_a), self.map.road_lanes(road_b)
        dist = dijkstra(lane_graph(self.map), indices=lanes_a.astype(np.int64))
        return bool(np.isfinite(np.asarray(dist).reshape(len(lanes_a), -1)[:, lanes_b]).any())

    def position(self, path: str, xy: tuple[float, float], radius: float) -> bool:
        bounds = getattr(self.map, "bounds", None)
        if bounds is None or len(bounds) != 4:
            return True
        xmin, ymin, xmax, ymax = (float(b) for b in bounds)
        x, y = xy
        if not (xmin - radius <= x <= xmax + radius and ymin - radius <= y <= ymax + radius):
            self.add(
                path,
                f"({x:g}, {y:g}) lies outside the map bounds x {xmin:.1f}..{xmax:.1f}, y {ymin:.1f}..{ymax:.1f}",
            )
            return False
        return True

    # ------------------------------------------------------------------ traffic
    def traffic(self, traffic: TrafficSpec) -> None:
        """Every road of every flow, trip and pedestrian flow; each road reachable from the one
        before; the departure lane, position and speed."""
        for kind, items in (("flows", traffic.flows), ("trips", traffic.trips)):
            for i, item in enumerate(items):
                self.departure(f"traffic.{kind}[{i}]", item)
        for i, ped in enumerate(traffic.pedestrians):
            self.road(f"traffic.pedestrians[{i}].origin", ped.origin)
            self.road(f"traffic.pedestrians[{i}].destination", ped.destination)

    def departure(self, path: str, item: Any) -> None:
        if item.route is not None:
            labels = [f"{path}.route[{j}]" for j in range(len(item.route))]
        else:
            labels = [f"{path}.origin", f"{path}.destination"]
        found = [self.road(label, road) for label, road in zip(labels, item.roads)]
        if found[0] is not None:
            first_lanes = found[0]
            lane = item.depart_lane if isinstance(item.depart_lane, int) else None
            ok = self.lane_offset(
                item.roads[0], first_lanes, lane, item.depart_pos,
                f"{path}.depart_lane", f"{path}.depart_pos", "depart_pos",
            )  # fmt: skip
            if ok and not isinstance(item.depart_speed, str):
                lanes = first_lanes if lane is None else [first_lanes[lane]]
                what = f"road {item.roads[0]!r}" if lane is None else f"lane {lane} of road {item.roads[0]!r}"
                self.speed(f"{path}.depart_speed", lanes, float(item.depart_speed), what)
        if not self.has_graph or any(lanes is None for lanes in found):
            return
        indices = [self.map.road_index_of[road] for road in item.roads]
        for k in range(1, len(indices)):
            a, b = indices[k - 1], indices[k]
            if a != b and not self.reaches(a, b):
                self.add(labels[k], f"no route from road {item.roads[k - 1]!r} to road {item.roads[k]!r}")
