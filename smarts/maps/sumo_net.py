"""Compile a SUMO ``.net.xml`` road network into a :class:`RoadMap`.

Internal (junction) lanes are kept so that vehicles inside a junction still have a lane, and so the
lane graph follows the exact turning paths SUMO drives. Lanes cars may not use (sidewalks, bike and
bus lanes, crossings, walking areas) are left out of the drivable lane graph.
"""

from __future__ import annotations

import hashlib
import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np

from smarts.maps.assemble import LaneSpec, assemble_road_map
from smarts.maps.errors import MapError
from smarts.maps.road_map import RoadMap

DEFAULT_LANE_WIDTH = 3.2
"""SUMO's lane width when a lane has no ``width`` attribute."""
DEFAULT_SPEED_LIMIT = 13.89
"""SUMO's default edge speed (50 km/h) for lanes without a ``speed`` attribute."""
_NON_DRIVING_FUNCTIONS = {"walkingarea", "crossing", "connector"}
_NO_OUTLINE_JUNCTIONS = {"internal", "dead_end"}


def read_map_bytes(path: Path) -> bytes:
    """The file's bytes, or a :class:`MapError` naming the file when it cannot be read."""
    try:
        return Path(path).read_bytes()
    except FileNotFoundError:
        raise MapError(f"{path}: map file not found") from None
    except IsADirectoryError:
        raise MapError(f"{path}: expected a map file but found a directory") from None
    except OSError as err:
        raise MapError(f"{path}: cannot read map file ({err.strerror})") from None


def compile_sumo_net(path: Path) -> RoadMap:
    """Parse a SUMO network (internal lanes included) and build all map arrays."""
    path = Path(path)
    content_hash, root = _read_net_root(path)
    lanes, lane_of_slot = _drivable_lanes(path, root)
    signals = _SignalReader(path, root)
    links, connections = _links(path, root, lanes, lane_of_slot, signals)
    junction_shapes = _junction_outlines(path, root)

    road_map = assemble_road_map(str(path), content_hash, lanes, sorted(links), junction_shapes)
    if connections:
        cols = list(zip(*connections))
        for name, values, dtype in zip(
            ("conn_from", "conn_via", "conn_to", "conn_tls", "conn_link", "conn_major", "conn_dir"),
            cols,
            (np.int32, np.int32, np.int32, np.int32, np.int32, bool, "<U1"),
        ):
            setattr(road_map, name, np.array(values, dtype=dtype))
    signals.store(road_map)
    return road_map


def _read_net_root(path: Path) -> tuple[str, ET.Element]:
    """The file's content hash and its parsed <net> root element."""
    data = read_map_bytes(path)
    content_hash = hashlib.sha256(data).hexdigest()
    try:
        root = ET.fromstring(data)
    except ET.ParseError as err:
        raise MapError(f"{path}: not a valid XML file ({err})") from None
    if root.tag != "net":
        raise MapError(f"{path}: expected a SUMO network with root <net>, found <{root.tag}>")
    return content_hash, root


def _drivable_lanes(path: Path, root: ET.Element) -> tuple[list[LaneSpec], dict[tuple[str, int], int]]:
    """Every lane a passenger car may drive, and (edge id, SUMO lane index) -> our lane index."""
    lanes: list[LaneSpec] = []
    lane_of_slot: dict[tuple[str, int], int] = {}  # (edge id, SUMO lane index) -> our lane
    for edge in root.findall("edge"):
        function = edge.get("function", "normal")
        if function in _NON_DRIVING_FUNCTIONS:
            continue
        edge_id = edge.get("id")
        if edge_id is None:
            raise MapError(f"{path}: an <edge> has no 'id' attribute")
        drivable = []
        for lane in edge.findall("lane"):
            if _allows_passenger_cars(lane):
                drivable.append((_int_attr(path, lane, "index"), lane))
        drivable.sort(key=lambda item: item[0])
        # Lane index counts drivable lanes only, so 0 is the rightmost lane a car may use even
        # when SUMO's index 0 is a sidewalk.
        for rank, (sumo_index, lane) in enumerate(drivable):
            lane_id = lane.get("id") or f"{edge_id}_{sumo_index}"
            lane_of_slot[(edge_id, sumo_index)] = len(lanes)
            lanes.append(
                LaneSpec(
                    lane_id=lane_id,
                    road_id=edge_id,
                    index=rank,
                    width=_float_attr(path, lane, "width", DEFAULT_LANE_WIDTH),
                    speed_limit=_float_attr(path, lane, "speed", DEFAULT_SPEED_LIMIT),
                    internal=function == "internal",
                    shape=_parse_shape(path, lane_id, lane.get("shape")),
                    sumo_length=_length_attr(path, lane),
                )
            )
    if not lanes:
        raise MapError(f"{path}: the network has no lanes that passenger cars may drive on")
    return lanes, lane_of_slot


def _links(
    path: Path,
    root: ET.Element,
    lanes: list[LaneSpec],
    lane_of_slot: dict[tuple[str, int], int],
    signals: _SignalReader,
) -> tuple[set[tuple[int, int]], list[tuple]]:
    """The lane graph's (from, to) successor pairs, and the connections between normal lanes.

    Each connection is (from, via, to, tls, link, major, dir); junctions and signals read them.
    """
    lane_of_id = {lane.lane_id: i for i, lane in enumerate(lanes)}
    links: set[tuple[int, int]] = set()
    via_targets: list[tuple[int, int]] = []
    connections: list[tuple] = []  # (from, via, to, tls, link, major, dir) of normal -> normal links
    for conn in root.findall("connection"):
        try:
            src = lane_of_slot.get((conn.get("from", ""), int(conn.get("fromLane", "-1"))))
            dst = lane_of_slot.get((conn.get("to", ""), int(conn.get("toLane", "-1"))))
        except ValueError:
            raise MapError(
                f"{path}: <connection from={conn.get('from')!r} to={conn.get('to')!r}> has a "
                f"non-integer fromLane/toLane"
            ) from None
        if src is None:
            continue
        via = conn.get("via")
        if not conn.get("from", "").startswith(":") and (via or dst is not None):
            connections.append(
                (
                    src,
                    lane_of_id.get(via, -1) if via else -1,
                    -1 if dst is None else dst,
                    signals.index(conn.get("tl")),
                    int(conn.get("linkIndex", "-1")),
                    conn.get("state", "M") in _MAJOR_STATES,
                    conn.get("dir", "s"),
                )
            )
        if via:
            via_lane = lane_of_id.get(via)
            if via_lane is None:
                continue
            links.add((src, via_lane))
            if dst is not None:
                via_targets.append((via_lane, dst))
        elif dst is not None:
            links.add((src, dst))
    # A via lane normally has its own connection rows; only when it has none, link it to the
    # target lane of the connection that named it.
    has_successor = {a for a, _ in links}
    links.update((v, d) for v, d in via_targets if v not in has_successor)
    return links, connections


def _junction_outlines(path: Path, root: ET.Element) -> list[np.ndarray]:
    """Outlines of the junctions that have an area (the drivable raster fills them)."""
    junction_shapes: list[np.ndarray] = []
    for junction in root.findall("junction"):
        if junction.get("type") in _NO_OUTLINE_JUNCTIONS or not junction.get("shape"):
            continue
        outline = _parse_shape(path, f"junction {junction.get('id')}", junction.get("shape"))
        if len(outline) >= 3:
            junction_shapes.append(outline)
    return junction_shapes


_MAJOR_STATES = ("M", "O")
"""Connection states with right of way (SUMO: M major, O major when signals are off)."""


class _SignalReader:
    """Traffic-light programs (``<tlLogic>``): the first program of each signal, fixed-time."""

    def __init__(self, path: Path, root: ET.Element):
        self.ids: list[str] = []
        self.offsets: list[float] = []
        self.durations: list[float] = []
        self.states: list[str] = []
        self.phase_offsets = [0]
        for logic in root.findall("tlLogic"):
            tls_id = logic.get("id")
            if tls_id is None or tls_id in self.ids:
                continue  # further programs of a signal are alternatives; the first one runs
            phases = logic.findall("phase")
            if not phases:
                raise MapError(f"{path}: <tlLogic id={tls_id!r}> has no <phase>")
            self.ids.append(tls_id)
            try:
                self.offsets.append(float(logic.get("offset", "0")))
            except ValueError:
                raise MapError(f"{path}: <tlLogic id={tls_id!r}> has a non-numeric offset") from None
            for phase in phases:
                duration = _float_attr(path, phase, "duration", float("nan"))
                if not duration > 0:
                    raise MapError(f"{path}: a <phase> of signal {tls_id!r} needs a positive duration")
                self.durations.append(duration)
                self.states.append(phase.get("state", ""))
            self.phase_offsets.append(len(self.durations))

    def index(self, tls_id: str | None) -> int:
        return self.ids.index(tls_id) if tls_id in self.ids else -1

    def store(self, road_map) -> None:
        road_map.tls_ids = list(self.ids)
        road_map.tls_offset = np.array(self.offsets, dtype=np.float64)
        road_map.tls_phase_offsets = np.array(self.phase_offsets, dtype=np.int64)
        road_map.tls_phase_duration = np.array(self.durations, dtype=np.float64)
        road_map.tls_phase_state = np.array(self.states, dtype=np.str_) if self.states else np.zeros(0, "<U1")


def _allows_passenger_cars(lane: ET.Element) -> bool:
    allow = lane.get("allow")
    if allow is not None:
        classes = set(allow.split())
        return "passenger" in classes or "all" in classes
    disallow = lane.get("disallow")
    if disallow is not None:
        classes = set(disallow.split())
        return not ("passenger" in classes or "all" in classes)
    return True


def _int_attr(path: Path, element: ET.Element, name: str) -> int:
    value = element.get(name)
    try:
        return int(value)  # type: ignore[arg-type]
    except (TypeError, ValueError):
        raise MapError(
            f"{path}: <{element.tag} id={element.get('id')!r}> needs an integer {name!r}, got {value!r}"
        ) from None


def _float_attr(path: Path, element: ET.Element, name: str, default: float) -> float:
    value = element.get(name)
    if value is None:
        return default
    try:
        number = float(value)
    except ValueError:
        number = float("nan")
    if not np.isfinite(number) or number <= 0:
        raise MapError(
            f"{path}: <{element.tag} id={element.get('id')!r}> needs a positive number for {name!r}, got {value!r}"
        )
    return number


def _length_attr(path: Path, lane: ET.Element) -> float | None:
    """SUMO's ``length`` of a lane (0 allowed: zero-length junction lanes), None when absent."""
    value = lane.get("length")
    if value is None:
        return None
    try:
        number = float(value)
    except ValueError:
        number = float("nan")
    if not np.isfinite(number) or number < 0:
        raise MapError(f"{path}: <lane id={lane.get('id')!r}> needs a length >= 0, got {value!r}")
    return number


def _parse_shape(path: Path, owner: str, shape: str | None) -> np.ndarray:
    """Parse SUMO's ``"x,y[,z] x,y[,z] ..."`` into float64[n, 2] (heights are dropped)."""
    if shape is None or not shape.strip():
        raise MapError(f"{path}: {owner!r} has no 'shape' attribute")
    coords = []
    for token in shape.split():
        parts = token.split(",")
        try:
            if len(parts) not in (2, 3):
                raise ValueError
            coords.append((float(parts[0]), float(parts[1])))
        except ValueError:
            raise MapError(
                f"{path}: {owner!r} has a malformed shape point {token!r} (expected 'x,y' or 'x,y,z')"
            ) from None
    xy = np.array(coords, dtype=np.float64)
    if not np.isfinite(xy).all():
        raise MapError(f"{path}: {owner!r} has a non-finite shape coordinate")
    return xy
