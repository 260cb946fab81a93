"""Waymo Open Motion scenarios: a TFRecord file of ``Scenario`` protocol buffers, without TensorFlow.

Each record is one scenario: ``timestamps_seconds`` (91 frames of 0.1 s in the motion dataset),
``tracks`` (one ``ObjectState`` per frame: centre, box size, heading, velocity and a ``valid``
flag) and ``map_features`` (lane centres with entry/exit lanes and left/right neighbours, road lines
and edges, stop signs). Vehicles and cyclists are replayed with their recorded boxes; frames a track
is not valid in are left out (a gap inside a track is interpolated). Lane centres become the map
(``smarts.replay.lane_map``), with the stop signs and the lanes they control
(``RoadMap.stop_sign_xy``, ``stop_sign_lane``).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from smarts.core.errors import ReplayError
from smarts.core.vehicle_table import VehicleType
from smarts.replay.argoverse2 import _aligned_heading
from smarts.replay.lane_map import DEFAULT_SPEED_LIMIT
from smarts.replay.ngsim import align
from smarts.replay.recording import DatasetMap, Recording, from_samples
from smarts.replay.tfrecord import read_records
from smarts.replay.waymo_proto import LANE_BIKE, OBJECT_CYCLIST, OBJECT_VEHICLE, scenario_class

MPH = 0.44704
"""m/s per mile per hour."""
OBJECT_TYPES = {OBJECT_VEHICLE: VehicleType.PASSENGER, OBJECT_CYCLIST: VehicleType.MOTORCYCLE}


def find_scenario(path: str | Path, scenario: str | None = None):
    """The parsed ``Scenario`` record named by id (or 0-based index), or the file's first."""
    from google.protobuf.message import DecodeError

    path = Path(path)
    cls = scenario_class()
    seen = []
    for index, data in enumerate(read_records(path)):
        try:
            message = cls.FromString(data)
        except DecodeError as err:
            raise ReplayError(f"{path}: record {index}: not a Scenario protocol buffer ({err})") from None
        if scenario is None or scenario == message.scenario_id or scenario == str(index):
            return message
        seen.append(message.scenario_id or str(index))
    if scenario is None:
        raise ReplayError(f"{path}: the file holds no scenario records")
    shown = ", ".join(seen[:8]) + (", ..." if len(seen) > 8 else "")
    raise ReplayError(f"{path}: replay.scenario: no scenario {scenario!r} (the file holds {len(seen)}: {shown})")


def read_waymo(
    path: str | Path,
    *,
    scenario: str | None = None,
    swap_xy: bool = False,
    flip_y: bool = False,
    offset: tuple[float, float] = (0.0, 0.0),
) -> Recording:
    path = Path(path)
    msg = find_scenario(path, scenario)
    where = f"{path} (scenario {msg.scenario_id or scenario or 0})"
    times = np.array(msg.timestamps_seconds, dtype=np.float64)
    dt = round(float(np.median(np.diff(times))), 6) if len(times) > 1 else 0.1  # 0.1, not 0.0999...
    if not dt > 0:
        raise ReplayError(f"{where}: timestamps_seconds: expected increasing times, got {times[:3].tolist()}...")
    vids, frames, xs, ys, hs, vs, lengths, widths, types = [], [], [], [], [], [], [], [], []
    for i, track in enumerate(msg.tracks):
        kind = OBJECT_TYPES.get(track.object_type)
        if kind is None:
            continue
        states = track.states
        if len(times) and len(states) != len(times):
            raise ReplayError(f"{where}: tracks[{i}].states: expected one per timestamp ({len(times)}), got {len(states)}")
        valid = np.array([s.valid for s in states], dtype=bool)
        if not valid.any():
            continue
        k = np.flatnonzero(valid)
        arr = np.array([(s.center_x, s.center_y, s.heading, s.velocity_x, s.velocity_y, s.length, s.width)
                        for s in states], dtype=np.float64)[k]  # fmt: skip
        first = int(k[0])
        size = arr[0, 5:7]
        if not (size > 0).all():
            raise ReplayError(f"{where}: tracks[{i}].states[{first}]: expected a positive length and width, got {size.tolist()}")
        vids.append(np.full(len(k), str(track.id)))
        frames.append(k)
        xs.append(arr[:, 0])
        ys.append(arr[:, 1])
        hs.append(arr[:, 2])
        vs.append(np.hypot(arr[:, 3], arr[:, 4]))
        lengths.append(np.full(len(k), size[0]))
        widths.append(np.full(len(k), size[1]))
        types.append(np.full(len(k), int(kind), dtype=np.int8))
    if not vids:
        raise ReplayError(f"{where}: tracks: no valid vehicle or cyclist states")
    x, y = align(np.concatenate(xs), np.concatenate(ys), swap_xy=swap_xy, flip_y=flip_y, offset=offset)
    heading = _aligned_heading(np.concatenate(hs), swap_xy, flip_y)
    road_map = read_map(msg, where, swap_xy=swap_xy, flip_y=flip_y, offset=offset)
    return from_samples(
        where, "waymo", np.concatenate(vids), np.concatenate(frames), x, y, heading, np.concatenate(vs),
        np.concatenate(lengths), np.concatenate(widths), np.concatenate(types), dt, road_map=road_map,
    )  # fmt: skip


def read_map(msg, where: str, *, swap_xy: bool, flip_y: bool, offset: tuple[float, float]) -> DatasetMap | None:
    """Lane centres (not bike lanes) and stop signs of a scenario's map features."""
    ids, lines, speeds, internal, succ, left, right, stops = [], [], [], [], [], [], [], []
    stop_lanes: list[str | None] = []
    widths = []
    boundaries = {}  # road line and road edge polylines by feature id, for lane widths
    for feature in msg.map_features:
        if feature.HasField("road_line") or feature.HasField("road_edge"):
            line = feature.road_line if feature.HasField("road_line") else feature.road_edge
            if len(line.polyline) >= 2:
                boundaries[feature.id] = np.array([(p.x, p.y) for p in line.polyline], dtype=np.float64)
    for feature in msg.map_features:
        if feature.HasField("lane"):
            lane = feature.lane
            if lane.type == LANE_BIKE or len(lane.polyline) < 2:
                continue
            xy = np.array([(p.x, p.y) for p in lane.polyline], dtype=np.float64)
            widths.append(lane_width(xy, lane.left_boundaries, lane.right_boundaries, boundaries))
            ids.append(str(feature.id))
            lines.append(np.stack(align(xy[:, 0], xy[:, 1], swap_xy=swap_xy, flip_y=flip_y, offset=offset), axis=1))
            speeds.append(lane.speed_limit_mph * MPH if lane.speed_limit_mph > 0 else DEFAULT_SPEED_LIMIT)
            internal.append(bool(lane.interpolating))
            succ.append([str(s) for s in lane.exit_lanes])
            left.append(str(lane.left_neighbors[0].feature_id) if len(lane.left_neighbors) else None)
            right.append(str(lane.right_neighbors[0].feature_id) if len(lane.right_neighbors) else None)
        elif feature.HasField("stop_sign"):
            p = feature.stop_sign.position
            sx, sy = align(np.array([p.x]), np.array([p.y]), swap_xy=swap_xy, flip_y=flip_y, offset=offset)
            stops.append((float(sx[0]), float(sy[0])))
            stop_lanes.append(str(feature.stop_sign.lane[0]) if len(feature.stop_sign.lane) else None)
    if not ids:
        return None
    return DatasetMap(
        source=where,
        lane_ids=ids,
        polylines=lines,
        widths=np.array(widths),  # 0 where no boundary is known: the compiler's default width
        speed_limits=np.array(speeds),
        internal=np.array(internal, dtype=bool),
        successors=succ,
        left=left,
        right=right,
        stop_signs=np.array(stops, dtype=np.float64).reshape(-1, 2),
        stop_sign_lanes=stop_lanes,
    )


MAX_HALF_WIDTH = 3.0
"""m: a boundary farther than this from the lane centre is not the lane's edge (a gap, a median)."""


def lane_width(centre: np.ndarray, left_segments, right_segments, boundaries: dict) -> float:
    """A lane's width from its boundary segments (road lines and edges beside it): the median
    distance from its centre points to each side's boundary, summed; one side known counts twice;
    0 when neither is (the dataset gives no width of its own)."""
    sides = []
    for segments in (left_segments, right_segments):
        distances = []
        for seg in segments:
            line = boundaries.get(seg.boundary_feature_id)
            if line is None:
                continue
            lo, hi = max(seg.lane_start_index, 0), min(seg.lane_end_index, len(centre) - 1)
            if hi < lo:
                continue
            distances.append(_point_polyline_distance(centre[lo : hi + 1], line))
        if distances:
            d = float(np.median(np.concatenate(distances)))
            sides.append(d if d <= MAX_HALF_WIDTH else None)
        else:
            sides.append(None)
    known = [d for d in sides if d is not None and d > 0.5]
    if not known:
        return 0.0
    return float(sum(known)) if len(known) == 2 else 2.0 * known[0]


def _point_polyline_distance(points: np.ndarray, line: np.ndarray) -> np.ndarray:
    """Distance from each point to the nearest segment of a polyline (vectorised)."""
    a, b = line[:-1], line[1:]
    ab = b - a
    denom = np.maximum((ab * ab).sum(axis=1), 1e-12)
    ap = points[:, None, :] - a[None, :, :]
    t = np.clip((ap * ab[None]).sum(axis=2) / denom[None], 0.0, 1.0)
    closest = a[None] + t[..., None] * ab[None]
    return np.sqrt(((points[:, None, :] - closest) ** 2).sum(axis=2)).min(axis=1)
