"""A scenario's traffic spec as a SUMO route file, checked against the map before SUMO starts.

SUMO reports a bad route only when the vehicle is due to depart, which can be minutes into an
episode. Every road, vehicle type and connection is therefore checked here, once, and a problem is
raised as a :class:`ScenarioError` naming the scenario field (``traffic.flows[2].route`` ...).

Flows and trips name roads only (``from``/``to``/``via``): SUMO's router picks the lanes, exactly
as it would for a hand-written scenario. Density levels become generated flows from every entry
road to every exit road reachable from it (see :func:`smarts.traffic.density.density_flows`).
"""

from __future__ import annotations

import functools
import math
import os
import xml.etree.ElementTree as ET
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from smarts.core.errors import MapError, NoRouteError, ScenarioError
from smarts.core.spec.traffic import (
    DEFAULT_VEHICLE_TYPES,
    DENSITY_LEVELS,
    DEPART_LANES,
    DEPART_SPEEDS,
    FlowSpec,
    PedestrianFlowSpec,
    TrafficSpec,
    TripSpec,
    VehicleTypeSpec,
)
from smarts.core.vehicle_table import VEHICLE_DIMENSIONS, VehicleType
from smarts.maps import RoadMap, shortest_route, sumo_net_path
from smarts.traffic.density import density_flows

AGENT_VTYPE = "smarts.agent"
"""SUMO type of the vehicles that mirror agents (their size is set per vehicle)."""
VEHICLE_BASES = {
    "passenger": VehicleType.PASSENGER,
    "bus": VehicleType.BUS,
    "truck": VehicleType.TRUCK,
    "motorcycle": VehicleType.MOTORCYCLE,
}
"""Base of a vehicle type -> our vehicle type; the base name is also SUMO's vClass."""


@dataclass(frozen=True)
class VehicleTypeInfo:
    """What the vehicle table needs about a SUMO vType: our type and the box size."""

    vtype: VehicleType
    length: float
    width: float
    height: float


def vehicle_type_info(spec: VehicleTypeSpec) -> VehicleTypeInfo:
    """Box size of a type: its own values, else the dimensions of its base type."""
    base = VEHICLE_BASES[spec.base]
    length, width, height, _ = VEHICLE_DIMENSIONS[base]
    return VehicleTypeInfo(
        base,
        float(spec.length if spec.length is not None else length),
        float(spec.width if spec.width is not None else width),
        float(spec.height if spec.height is not None else height),
    )


# ---------------------------------------------------------------------------- checks
class _Checker:
    """Checks of one traffic spec against one map; raises ``ScenarioError`` naming the field."""

    def __init__(self, traffic: TrafficSpec, road_map: RoadMap, net_file: Path | None):
        self.traffic = traffic
        self.road_map = road_map
        self.net_file = net_file

    def error(self, where: str, message: str) -> ScenarioError:
        return ScenarioError(f"traffic.{where}: {message}")

    def run(self) -> None:
        t = self.traffic
        if t.density not in DENSITY_LEVELS:
            raise self.error("density", f"expected one of {', '.join(DENSITY_LEVELS)}, got {t.density!r}")
        for name, spec in t.vehicle_types.items():
            self.vehicle_type(f"vehicle_types.{name}", name, spec)
        ids: dict[str, str] = {}
        for i, flow in enumerate(t.flows):
            where = f"flows[{i}]"
            self.unique_id(ids, flow.id, where)
            self.departures(where, flow)
            self.rate(where, flow.rate, flow.probability)
            self.interval(where, flow.begin, flow.end)
        for i, trip in enumerate(t.trips):
            where = f"trips[{i}]"
            self.unique_id(ids, trip.id, where)
            self.departures(where, trip)
            if not (_finite(trip.depart) and trip.depart >= 0):
                raise self.error(f"{where}.depart", f"expected a time >= 0 s, got {trip.depart!r}")
        if t.pedestrians:
            sidewalks = _sidewalk_edges(self.net_file) if self.net_file is not None else None
            for i, ped in enumerate(t.pedestrians):
                where = f"pedestrians[{i}]"
                self.unique_id(ids, ped.id, where)
                self.pedestrians(where, ped, sidewalks)

    def unique_id(self, ids: dict[str, str], ident: str, where: str) -> None:
        if not isinstance(ident, str) or not ident or any(c.isspace() for c in ident):
            raise self.error(f"{where}.id", f"expected a non-empty id without spaces, got {ident!r}")
        if ident in ids:
            raise self.error(f"{where}.id", f"id {ident!r} is already used by traffic.{ids[ident]}")
        ids[ident] = where

    def vehicle_type(self, where: str, name: str, spec: VehicleTypeSpec) -> None:
        if name == AGENT_VTYPE:
            raise self.error(where, f"the type name {AGENT_VTYPE!r} is reserved for agent vehicles")
        if spec.base not in VEHICLE_BASES:
            raise self.error(f"{where}.base", f"expected one of {', '.join(VEHICLE_BASES)}, got {spec.base!r}")
        positive = (
            "length",
            "width",
            "height",
            "max_speed",
            "accel",
            "decel",
            "emergency_decel",
            "tau",
            "speed_factor",
        )
        for attr in positive:
            value = getattr(spec, attr)
            if value is not None and not (_finite(value) and value > 0):
                raise self.error(f"{where}.{attr}", f"expected a positive number, got {value!r}")
        for attr in (
            "min_gap",
            "speed_dev",
            "lc_strategic",
            "lc_cooperative",
            "lc_speed_gain",
            "lc_keep_right",
        ):
            value = getattr(spec, attr)
            if not (_finite(value) and value >= 0):
                raise self.error(f"{where}.{attr}", f"expected a number >= 0, got {value!r}")
        if not (_finite(spec.sigma) and 0 <= spec.sigma <= 1):
            raise self.error(f"{where}.sigma", f"expected a number in [0, 1], got {spec.sigma!r}")

    def known_type(self, where: str, name: str) -> VehicleTypeSpec:
        try:
            return self.traffic.vehicle_type(name)
        except (KeyError, TypeError):
            known = sorted(set(self.traffic.vehicle_types) | set(DEFAULT_VEHICLE_TYPES))
            raise self.error(where, f"unknown vehicle type {name!r}; known types: {', '.join(known)}") from None

    def road(self, where: str, road_id: object) -> int:
        rm = self.road_map
        if not isinstance(road_id, str) or road_id not in rm.road_index_of:
            raise self.error(where, f"unknown road {road_id!r} (map {rm.source!r})")
        road = rm.road_index_of[road_id]
        if rm.lane_internal[rm.road_lanes(road)].any():
            raise self.error(where, f"road {road_id!r} lies inside a junction; name a normal road")
        return road

    def departures(self, where: str, item: FlowSpec | TripSpec) -> None:
        """Path, vehicle type and depart lane/speed/position of a flow or trip."""
        self.known_type(f"{where}.vehicle_type", item.vehicle_type)
        if item.route:
            if not isinstance(item.route, (list, tuple)):
                raise self.error(f"{where}.route", f"expected a list of road ids, got {item.route!r}")
            roads = [self.road(f"{where}.route[{k}]", r) for k, r in enumerate(item.route)]
            labels = [f"{where}.route"] * len(roads)
        else:
            if item.origin is None or item.destination is None:
                raise self.error(where, "needs a 'route' or both 'origin' and 'destination'")
            roads = [
                self.road(f"{where}.origin", item.origin),
                self.road(f"{where}.destination", item.destination),
            ]
            labels = [f"{where}.origin", f"{where}.destination"]
        for k in range(1, len(roads)):
            if not self.connects(roads[k - 1], roads[k]):
                a, b = (self.road_map.road_ids[r] for r in (roads[k - 1], roads[k]))
                raise self.error(labels[k], f"road {a!r} does not connect to {b!r}")
        first_lanes = self.road_map.road_lanes(roads[0])
        lane = item.depart_lane
        if isinstance(lane, bool) or not (
            lane in DEPART_LANES or (isinstance(lane, (int, np.integer)) and 0 <= lane < len(first_lanes))
        ):
            raise self.error(
                f"{where}.depart_lane",
                f"expected one of {', '.join(DEPART_LANES)} or a lane index 0..{len(first_lanes) - 1} "
                f"of road {self.road_map.road_ids[roads[0]]!r}, got {lane!r}",
            )
        speed = item.depart_speed
        if isinstance(speed, bool) or not (
            speed in DEPART_SPEEDS or (isinstance(speed, (int, float)) and _finite(speed) and speed >= 0)
        ):
            raise self.error(
                f"{where}.depart_speed",
                f"expected one of {', '.join(DEPART_SPEEDS)} or a speed >= 0 m/s, got {speed!r}",
            )
        length = float(self.road_map.lane_length[first_lanes].min())
        pos = item.depart_pos
        if not (isinstance(pos, (int, float)) and _finite(pos) and 0 <= pos <= length):
            raise self.error(
                f"{where}.depart_pos",
                f"expected metres in [0, {length:.1f}] along road {self.road_map.road_ids[roads[0]]!r}, got {pos!r}",
            )

    def connects(self, a: int, b: int) -> bool:
        """Whether some lane of road ``a`` leads to some lane of road ``b`` in the lane graph."""
        lanes_a, lanes_b = self.road_map.road_lanes(a), self.road_map.road_lanes(b)
        for la in lanes_a:
            for lb in lanes_b:
                try:
                    shortest_route(self.road_map, int(la), int(lb))
                    return True
                except NoRouteError:
                    continue
        return False

    def rate(self, where: str, rate: float | None, probability: float | None) -> None:
        if (rate is None) == (probability is None):
            raise self.error(where, "give exactly one of 'rate' (vehicles per hour) or 'probability'")
        if rate is not None and not (_finite(rate) and rate > 0):
            raise self.error(f"{where}.rate", f"expected a positive rate per hour, got {rate!r}")
        if probability is not None and not (_finite(probability) and 0 < probability <= 1):
            raise self.error(
                f"{where}.probability",
                f"expected a probability in (0, 1] per second, got {probability!r}",
            )

    def interval(self, where: str, begin: float, end: float) -> None:
        if not (_finite(begin) and begin >= 0):
            raise self.error(f"{where}.begin", f"expected a time >= 0 s, got {begin!r}")
        if not (_finite(end) and end > begin):
            raise self.error(f"{where}.end", f"expected a time after begin ({begin}), got {end!r}")

    def pedestrians(self, where: str, ped: PedestrianFlowSpec, sidewalks: set[str] | None) -> None:
        self.rate(where, ped.rate, ped.probability)
        self.interval(where, ped.begin, ped.end)
        if not (_finite(ped.speed) and ped.speed > 0):
            raise self.error(f"{where}.speed", f"expected a positive walking speed, got {ped.speed!r}")
        for attr in ("origin", "destination"):
            road = getattr(ped, attr)
            if sidewalks is None:
                self.road(f"{where}.{attr}", road)
            elif road not in sidewalks:
                raise self.error(
                    f"{where}.{attr}",
                    f"road {road!r} has no sidewalk; pedestrians need a map with sidewalks and "
                    "crossings (e.g. builtin:intersection_4way_1lane_peds)",
                )


def check_traffic(traffic: TrafficSpec, road_map: RoadMap, net_file: Path | None = None) -> None:
    """Raise ``ScenarioError`` naming the field of the first problem in ``traffic`` on this map.

    ``net_file`` (the SUMO network) is needed to check that pedestrians have sidewalks.
    """
    _Checker(traffic, road_map, net_file).run()


@functools.lru_cache(maxsize=8)
def _sidewalk_edges_cached(path: str, mtime: float) -> frozenset[str]:
    edges = set()
    for _, element in ET.iterparse(path):
        if element.tag != "edge":
            continue
        if element.get("function", "normal") == "normal":
            for lane in element.findall("lane"):
                allow = set((lane.get("allow") or "").split())
                if "pedestrian" in allow and "passenger" not in allow and "all" not in allow:
                    edges.add(element.get("id"))
                    break
        element.clear()
    return frozenset(edges)


def _sidewalk_edges(net_file: Path) -> set[str]:
    """Normal edges of a SUMO network that have a pedestrian-only lane (a sidewalk)."""
    return set(_sidewalk_edges_cached(str(net_file), os.path.getmtime(net_file)))


def _finite(value: object) -> bool:
    return (
        isinstance(value, (int, float, np.floating, np.integer))
        and not isinstance(value, bool)
        and math.isfinite(value)
    )


# ---------------------------------------------------------------------------- writing
def used_vehicle_types(traffic: TrafficSpec, flows: Sequence[FlowSpec]) -> dict[str, VehicleTypeSpec]:
    """The types the flows and trips use (each once, in order of first use)."""
    names = [f.vehicle_type for f in flows] + [t.vehicle_type for t in traffic.trips]
    return {name: traffic.vehicle_type(name) for name in dict.fromkeys(names)}


def all_flows(traffic: TrafficSpec, road_map: RoadMap) -> list[FlowSpec]:
    """The listed flows followed by the density level's generated flows."""
    return list(traffic.flows) + density_flows(traffic, road_map)


def write_route_file(
    traffic: TrafficSpec,
    road_map: RoadMap,
    out_dir: str | os.PathLike,
    seed: int,
    net_file: str | os.PathLike | None = None,
) -> Path:
    """Check ``traffic`` against the map and write it as ``<out_dir>/traffic.rou.xml``.

    The file is the same for every ``seed``: everything random in it (probability flows, speed
    factors, random depart lanes) is drawn by SUMO from its ``--seed`` option, so one file serves
    every episode. ``net_file`` defaults to the SUMO network of ``road_map.source``.
    """
    del seed  # see above
    if net_file is None:
        try:
            net_file = sumo_net_path(road_map.source)
        except MapError:
            net_file = None
    check_traffic(traffic, road_map, None if net_file is None else Path(net_file))
    flows = all_flows(traffic, road_map)
    root = ET.Element("routes")
    root.append(ET.Comment(f" traffic for map {Path(road_map.source).name} "))
    for name, spec in used_vehicle_types(traffic, flows).items():
        root.append(_vtype_element(name, spec))
    ET.SubElement(root, "vType", {"id": AGENT_VTYPE, "vClass": "passenger", "speedDev": "0"})
    timed: list[tuple[float, int, ET.Element]] = []
    for flow in flows:
        timed.append((float(flow.begin), len(timed), _flow_element(flow, traffic, road_map)))
    for trip in traffic.trips:
        timed.append((float(trip.depart), len(timed), _trip_element(trip, traffic, road_map)))
    for ped in traffic.pedestrians:
        timed.append((float(ped.begin), len(timed), _person_flow_element(ped)))
    # SUMO reads route files as a stream and needs departures in time order.
    for _, _, element in sorted(timed, key=lambda item: item[:2]):
        root.append(element)
    ET.indent(root)
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    path = out / "traffic.rou.xml"
    path.write_text('<?xml version="1.0" encoding="UTF-8"?>\n' + ET.tostring(root, encoding="unicode") + "\n")
    return path


def _vtype_element(name: str, spec: VehicleTypeSpec) -> ET.Element:
    info = vehicle_type_info(spec)
    attrib = {
        "id": name,
        "vClass": spec.base,
        "length": _num(info.length),
        "width": _num(info.width),
        "height": _num(info.height),
        "maxSpeed": _num(spec.max_speed),
        "accel": _num(spec.accel),
        "decel": _num(spec.decel),
        "emergencyDecel": _num(max(spec.emergency_decel, spec.decel)),
        "tau": _num(spec.tau),
        "minGap": _num(spec.min_gap),
        "sigma": _num(spec.sigma),
        "speedFactor": _num(spec.speed_factor),
        "speedDev": _num(spec.speed_dev),
        "lcStrategic": _num(spec.lc_strategic),
        "lcCooperative": _num(spec.lc_cooperative),
        "lcSpeedGain": _num(spec.lc_speed_gain),
        "lcKeepRight": _num(spec.lc_keep_right),
    }
    return ET.Element("vType", attrib)


def _path_attrib(roads: list[str]) -> dict[str, str]:
    attrib = {"from": roads[0], "to": roads[-1]}
    if len(roads) > 2:
        attrib["via"] = " ".join(roads[1:-1])
    return attrib


def _depart_attrib(item: FlowSpec | TripSpec, traffic: TrafficSpec, road_map: RoadMap) -> dict[str, str]:
    """SUMO depart attributes. ``depart_pos`` is where the box centre starts (our convention),
    so SUMO, which places the front bumper, gets ``depart_pos + length / 2``; 0 keeps the whole
    vehicle on the road (SUMO's "base"). It is metres along the lane's shape, scaled to SUMO's
    lane length (``RoadMap.to_sumo_pos``) where the network gives lanes another length."""
    first_road = road_map.road(item.roads[0])
    lanes = road_map.road_lanes(first_road)
    lane = item.depart_lane
    if isinstance(lane, str):
        depart_lane = lane
    else:  # our index counts car lanes only; SUMO's counts sidewalks too
        depart_lane = road_map.lane_ids[int(lanes[int(lane)])].rsplit("_", 1)[1]
    speed = item.depart_speed
    depart_speed = speed if isinstance(speed, str) else _num(speed)
    length = vehicle_type_info(traffic.vehicle_type(item.vehicle_type)).length
    if isinstance(lane, str):  # SUMO picks the lane: the shortest one bounds the position
        lane_for_pos = int(lanes[int(np.argmin(road_map.lane_length[lanes]))])
    else:
        lane_for_pos = int(lanes[int(lane)])
    lane_length = float(road_map.lane_length[lane_for_pos])
    if item.depart_pos <= 0:
        depart_pos = "base"
    else:
        front = min(max(item.depart_pos + length / 2, length), lane_length)
        depart_pos = _num(road_map.to_sumo_pos(lane_for_pos, front))
    return {
        "type": item.vehicle_type,
        "departLane": depart_lane,
        "departSpeed": depart_speed,
        "departPos": depart_pos,
    }


def _flow_element(flow: FlowSpec, traffic: TrafficSpec, road_map: RoadMap) -> ET.Element:
    attrib = {"id": flow.id, "begin": _num(flow.begin), "end": _num(flow.end)}
    if flow.rate is not None:
        attrib["vehsPerHour"] = _num(flow.rate)
    else:
        attrib["probability"] = _num(flow.probability)
    attrib.update(_path_attrib(flow.roads))
    attrib.update(_depart_attrib(flow, traffic, road_map))
    return ET.Element("flow", attrib)


def _trip_element(trip: TripSpec, traffic: TrafficSpec, road_map: RoadMap) -> ET.Element:
    attrib = {"id": trip.id, "depart": _num(trip.depart)}
    attrib.update(_path_attrib(trip.roads))
    attrib.update(_depart_attrib(trip, traffic, road_map))
    return ET.Element("trip", attrib)


def _person_flow_element(ped: PedestrianFlowSpec) -> ET.Element:
    attrib = {"id": ped.id, "begin": _num(ped.begin), "end": _num(ped.end)}
    if ped.rate is not None:
        attrib["perHour"] = _num(ped.rate)
    else:
        attrib["probability"] = _num(ped.probability)
    element = ET.Element("personFlow", attrib)
    ET.SubElement(element, "walk", {"from": ped.origin, "to": ped.destination, "speed": _num(ped.speed)})
    return element


def _num(value: float) -> str:
    text = f"{float(value):.6f}".rstrip("0").rstrip(".")
    return "0" if text in ("-0", "") else text
