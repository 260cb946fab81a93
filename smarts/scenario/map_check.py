"""Checking a scenario against its compiled map: every road, lane and offset its missions and
traffic name exists, with errors naming the field."""

from __future__ import annotations

import difflib
from pathlib import Path
from typing import Any

from smarts.core.errors import ScenarioError
from smarts.core.spec.scenario import ScenarioSpec
from smarts.core.spec.traffic import TrafficSpec


def check_scenario_map(spec: ScenarioSpec, road_map: Any) -> None:
    """Check every mission's and every traffic entry's roads, lanes and offsets against the map.

    ``road_map`` needs ``road_index_of``, ``road_lanes(road)`` and ``lane_length`` (and uses
    ``lane_internal`` and ``bounds`` when present), as on :class:`smarts.maps.road_map.RoadMap`.
    """
    checker = _MapChecker(spec.source, road_map)
    for i, agent in enumerate(spec.agents):
        where = f"agents[{i}].mission"
        start = agent.mission.start
        if start.take_over is None:  # a taken-over vehicle starts where its trip departs
            checker.road_lane(f"{where}.start", start.road, start.lane, start.offset)
        goal = agent.mission.goal
        if goal.kind == "road":
            checker.road_lane(f"{where}.goal", goal.road, goal.lane, goal.offset)
        elif goal.kind == "position":
            checker.position(f"{where}.goal.position", goal.position, goal.radius)
        for j, road in enumerate(agent.mission.route_via):
            checker.road(f"{where}.route_via[{j}]", road)
    if spec.traffic is not None:
        checker.traffic(spec.traffic)


class _MapChecker:
    """Checks mission references against a compiled map, with errors naming the field."""

    def __init__(self, source: str, road_map: Any) -> None:
        self.source = source
        self.map = road_map
        self.map_name = Path(str(getattr(road_map, "source", "") or "map")).name

    def error(self, path: str, message: str) -> ScenarioError:
        return ScenarioError(f"{self.source}: {path}: {message}")

    def road(self, path: str, road: str) -> Any:
        index = self.map.road_index_of.get(road)
        if index is None:
            normal = sorted(r for r in self.map.road_index_of if not r.startswith(":"))
            hint = difflib.get_close_matches(road, normal, n=1)
            suggestion = f" (did you mean {hint[0]!r}?)" if hint else ""
            shown = ", ".join(normal[:30]) + (", ..." if len(normal) > 30 else "")
            raise self.error(
                path, f"map {self.map_name!r} has no road {road!r}{suggestion}; roads: {shown}"
            )
        lanes = self.map.road_lanes(index)
        internal = getattr(self.map, "lane_internal", None)
        if road.startswith(":") or (
            internal is not None and len(lanes) and bool(internal[lanes[0]])
        ):
            raise self.error(path, f"road {road!r} lies inside a junction; name a normal road")
        return lanes

    def road_lane(self, path: str, road: str, lane: int | None, offset: float | None) -> None:
        lanes = self.road(f"{path}.road", road)
        self.lane_offset(road, lanes, lane, offset, f"{path}.lane", f"{path}.offset", "offset")

    def lane_offset(
        self,
        road: str,
        lanes: Any,
        lane: int | None,
        offset: float | None,
        lane_path: str,
        offset_path: str,
        offset_name: str,
    ) -> None:
        """The lane exists on the road and the offset lies on it (on every lane when None)."""
        n = len(lanes)
        if lane is not None and lane >= n:
            raise self.error(lane_path, f"road {road!r} has {n} lanes (0..{n - 1}), got {lane}")
        if offset is None:
            return
        candidates = [lanes[lane]] if lane is not None else list(lanes)
        length = min(float(self.map.lane_length[i]) for i in candidates)
        if offset > length:
            which = f"lane {lane} of road {road!r}" if lane is not None else f"road {road!r}"
            raise self.error(
                offset_path, f"{which} is {length:.1f} m long, got {offset_name} {offset:g}"
            )

    def traffic(self, traffic: TrafficSpec) -> None:
        """Every road of every flow, trip and pedestrian flow; the departure lane and position."""
        for kind, items in (("flows", traffic.flows), ("trips", traffic.trips)):
            for i, item in enumerate(items):
                path = f"traffic.{kind}[{i}]"
                if item.route is not None:
                    found = [self.road(f"{path}.route[{j}]", r) for j, r in enumerate(item.route)]
                    first_lanes = found[0]
                else:
                    first_lanes = self.road(f"{path}.origin", item.origin)
                    self.road(f"{path}.destination", item.destination)
                lane = item.depart_lane if isinstance(item.depart_lane, int) else None
                self.lane_offset(
                    item.roads[0],
                    first_lanes,
                    lane,
                    item.depart_pos,
                    f"{path}.depart_lane",
                    f"{path}.depart_pos",
                    "depart_pos",
                )
        for i, ped in enumerate(traffic.pedestrians):
            self.road(f"traffic.pedestrians[{i}].origin", ped.origin)
            self.road(f"traffic.pedestrians[{i}].destination", ped.destination)

    def position(self, path: str, xy: tuple[float, float], radius: float) -> None:
        bounds = getattr(self.map, "bounds", None)
        if bounds is None:
            return
        xmin, ymin, xmax, ymax = (float(b) for b in bounds)
        x, y = xy
        if not (xmin - radius <= x <= xmax + radius and ymin - radius <= y <= ymax + radius):
            raise self.error(
                path,
                f"({x:g}, {y:g}) lies outside the map bounds x {xmin:.1f}..{xmax:.1f}, "
                f"y {ymin:.1f}..{ymax:.1f}",
            )
