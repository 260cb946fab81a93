"""Waymo Open Motion scenarios: a TFRecord file of ``Scenario`` protocol buffers, without TensorFlow.

Each record is one scenario: ``timestamps_seconds`` (91 frames about 0.1 s apart in the motion
dataset; the replay runs on these recorded times), ``tracks`` (one ``ObjectState`` per frame: centre,
box size, heading, velocity and a ``valid`` flag), ``dynamic_map_states`` (per frame, the state of
every observed traffic signal and the lane it controls) and ``map_features`` (lane centres with
entry/exit lanes and the stretches where left/right neighbours run alongside, road lines and edges,
stop signs, crosswalks, speed bumps).

Vehicles, pedestrians and cyclists are replayed as their own kinds; frames a track is not valid in
are left out (a gap inside a track is interpolated). A box's size changes along a track as the
detector's estimate does (it grows as more of the object comes into view); each track keeps the
median of its valid states' sizes, which ignores the partial views at the ends. Lane centres become
the map (``smarts.replay.lane_map``), with the stop signs, the signal-controlled lanes (whose
recorded states drive the simulator's signals), crosswalks, bike lanes and speed bumps.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from smarts.core.errors import ReplayError
from smarts.replay.lane_map import DEFAULT_SPEED_LIMIT
from smarts.replay.ngsim import align, check_file
from smarts.replay.recording import (
    BIKE_LANE,
    CROSSWALK,
    MAX_COORDINATE,
    MAX_SIZE,
    MAX_SPEED,
    SPEED_BUMP,
    DatasetMap,
    ObjectKind,
    Recording,
    from_samples,
    table_type,
)
from smarts.replay.tfrecord import read_records
from smarts.replay.waymo_proto import (
    LANE_BIKE,
    OBJECT_CYCLIST,
    OBJECT_PEDESTRIAN,
    OBJECT_VEHICLE,
    ROAD_LINE_KINDS,
    scenario_class,
)

MPH = 0.44704
"""m/s per mile per hour."""
OBJECT_KINDS = {OBJECT_VEHICLE: ObjectKind.PASSENGER, OBJECT_PEDESTRIAN: ObjectKind.PEDESTRIAN,
                OBJECT_CYCLIST: ObjectKind.CYCLIST}  # fmt: skip
OBJECT_NAMES = {0: "an object of unset type", 4: "an object of type other"}
TF_EXAMPLE_KEYS = (b"state/current/x", b"roadgraph_samples/xyz", b"traffic_light_state/current/state")
"""Feature names of the dataset's flattened tf.Example files, which hold no Scenario."""
BIKE_LANE_WIDTH = 1.5
"""m: a bike lane's width where its boundaries are not known."""


def find_scenario(path: str | Path, scenario: str | None = None):
    """The parsed ``Scenario`` record named by id (or 0-based index), or the file's first."""
    from google.protobuf.message import DecodeError

    path = Path(path)
    check_file(path, "waymo")
    cls = scenario_class()
    seen = []
    for index, data in enumerate(read_records(path)):
        if index == 0 and any(key in data for key in TF_EXAMPLE_KEYS):
            raise ReplayError(
                f"{path}: holds tf.Example records (the motion dataset's tf_example files); replay reads its Scenario "
                "files (the scenario/ folder, e.g. training.tfrecord-00000-of-01000)"
            )
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
    """The tracks, signal states and map of one scenario of a Waymo Open Motion TFRecord."""
    from smarts.replay.argoverse2 import aligned_heading

    path = Path(path)
    msg = find_scenario(path, scenario)
    where = f"{path} (scenario {msg.scenario_id or scenario or 0})"
    times = np.array(msg.timestamps_seconds, dtype=np.float64)
    if not np.isfinite(times).all():
        k = int(np.flatnonzero(~np.isfinite(times))[0])
        raise ReplayError(f"{where}: timestamps_seconds[{k}]: expected a finite time, got {times[k]:g}")
    if len(times) > 1 and not (np.diff(times) > 0).all():
        k = int(np.flatnonzero(~(np.diff(times) > 0))[0])
        raise ReplayError(f"{where}: timestamps_seconds[{k + 1}]: expected increasing times, got {times[k]:g} then "
                          f"{times[k + 1]:g}")  # fmt: skip
    # the nominal interval (0.1 s), for display and beyond the ends; the clock follows ``times``
    dt = round(float(np.median(np.diff(times))), 3) if len(times) > 1 else 0.1
    dt = dt if dt > 0 else float(np.median(np.diff(times)))
    n_frames = len(times)
    vids, frames, xs, ys, hs, vs, lengths, widths, kinds = [], [], [], [], [], [], [], [], []
    skipped: dict[str, str] = {}
    for i, track in enumerate(msg.tracks):
        kind = OBJECT_KINDS.get(track.object_type)
        if kind is None:
            skipped[str(track.id)] = OBJECT_NAMES.get(track.object_type, f"an object of type {track.object_type}")
            continue
        states = track.states
        if n_frames and len(states) != n_frames:
            raise ReplayError(
                f"{where}: tracks[{i}].states: expected one per timestamp ({n_frames}), got {len(states)}"
            )
        valid = np.array([s.valid for s in states], dtype=bool)
        if not valid.any():
            skipped[str(track.id)] = f"a {kind.name.lower()} never valid"
            continue
        k = np.flatnonzero(valid)
        arr = np.array([(s.center_x, s.center_y, s.heading, s.velocity_x, s.velocity_y, s.length, s.width)
                        for s in states], dtype=np.float64)[k]  # fmt: skip
        _check_states(where, i, k, arr)
        vids.append(np.full(len(k), str(track.id)))
        frames.append(k)
        xs.append(arr[:, 0])
        ys.append(arr[:, 1])
        hs.append(arr[:, 2])
        vs.append(np.hypot(arr[:, 3], arr[:, 4]))
        lengths.append(np.full(len(k), float(np.median(arr[:, 5]))))
        widths.append(np.full(len(k), float(np.median(arr[:, 6]))))
        kinds.append(np.full(len(k), int(kind), dtype=np.int8))
    if not vids:
        raise ReplayError(f"{where}: tracks: no valid vehicle, pedestrian or cyclist states")
    if not n_frames:  # no timestamps: the dataset's fixed rate
        times_arr = None
    else:
        times_arr = times - times[0]
    x, y = align(np.concatenate(xs), np.concatenate(ys), swap_xy=swap_xy, flip_y=flip_y, offset=offset)
    heading = aligned_heading(np.concatenate(hs), swap_xy, flip_y)
    kind = np.concatenate(kinds)
    vtype = np.array([int(table_type(k)) for k in range(len(ObjectKind))], np.int8)[kind]
    road_map = read_map(msg, where, swap_xy=swap_xy, flip_y=flip_y, offset=offset)
    states = None
    if road_map is not None:
        states = signal_states(msg, road_map, n_frames, where, swap_xy=swap_xy, flip_y=flip_y, offset=offset)
    rec = from_samples(
        where, "waymo", np.concatenate(vids), np.concatenate(frames), x, y, heading, np.concatenate(vs),
        np.concatenate(lengths), np.concatenate(widths), vtype, dt, road_map=road_map, kind=kind, times=times_arr,
        signal_states=states, skipped=skipped,
    )  # fmt: skip
    if 0 <= msg.sdc_track_index < len(msg.tracks):
        sdc = str(msg.tracks[msg.sdc_track_index].id)
        rec.ego = sdc if sdc in rec.index_of else None
    return rec


STATE_FIELDS = ("center_x", "center_y", "heading", "velocity_x", "velocity_y", "length", "width")


def _check_states(where: str, track: int, frames: np.ndarray, arr: np.ndarray) -> None:
    """Every valid state's numbers finite and physical; else an error naming the track, state and field."""
    speed = np.hypot(arr[:, 3], arr[:, 4])
    bad = ~np.isfinite(arr)
    bad[:, :2] |= np.abs(arr[:, :2]) > MAX_COORDINATE
    bad[:, 3:5] |= (speed > MAX_SPEED)[:, None]
    bad[:, 5:7] |= ~(arr[:, 5:7] > 0) | (arr[:, 5:7] > MAX_SIZE)
    if not bad.any():
        return
    row, col = (int(v[0]) for v in np.nonzero(bad))
    value = float(arr[row, col])
    expected = "a finite number"
    if np.isfinite(value):
        expected = {5: "a positive size", 6: "a positive size"}.get(col, "a physical value")
        if col in (5, 6) and value > 0:
            expected = f"a size within {MAX_SIZE:g} m"
        elif col in (3, 4):
            expected = f"a speed within {MAX_SPEED:g} m/s"
        elif col in (0, 1):
            expected = f"a coordinate within +-{MAX_COORDINATE:g} m"
    raise ReplayError(f"{where}: tracks[{track}].states[{int(frames[row])}].{STATE_FIELDS[col]}: expected {expected}, "
                      f"got {value:g}")  # fmt: skip


def _points(feature, points, where: str, name: str) -> np.ndarray:
    xy = np.array([(p.x, p.y) for p in points], dtype=np.float64).reshape(-1, 2)
    bad = ~np.isfinite(xy).all(axis=1) | (np.abs(xy) > MAX_COORDINATE).any(axis=1)
    if bad.any():
        k = int(np.flatnonzero(bad)[0])
        raise ReplayError(f"{where}: map_features (id {feature.id}).{name}[{k}]: expected a finite position, got "
                          f"({xy[k, 0]:g}, {xy[k, 1]:g})")  # fmt: skip
    return xy


def read_map(msg, where: str, *, swap_xy: bool, flip_y: bool, offset: tuple[float, float]) -> DatasetMap | None:
    """Lane centres (not bike lanes: those become marks), stop signs, lines, edges, crosswalks and
    speed bumps of a scenario's map features."""

    def aligned(xy: np.ndarray) -> np.ndarray:
        return np.stack(align(xy[:, 0], xy[:, 1], swap_xy=swap_xy, flip_y=flip_y, offset=offset), axis=1)

    ids, lines, speeds, internal, succ, left, right, stops = [], [], [], [], [], [], [], []
    stop_lanes: list[str | None] = []
    widths = []
    marks, mark_kinds, drawn, drawn_kinds = [], [], [], []
    boundaries = {}  # road line and road edge polylines by feature id, for lane widths
    for feature in msg.map_features:
        if feature.HasField("road_line") or feature.HasField("road_edge"):
            is_line = feature.HasField("road_line")
            line = feature.road_line if is_line else feature.road_edge
            xy = _points(feature, line.polyline, where, "road_line.polyline" if is_line else "road_edge.polyline")
            if len(xy) >= 2:
                boundaries[feature.id] = xy
                drawn.append(aligned(xy))
                drawn_kinds.append(ROAD_LINE_KINDS.get(line.type, "other") if is_line else "edge")
    for feature in msg.map_features:
        if feature.HasField("lane"):
            lane = feature.lane
            if len(lane.polyline) < 2:
                continue
            xy = _points(feature, lane.polyline, where, "lane.polyline")
            width = lane_width(xy, lane.left_boundaries, lane.right_boundaries, boundaries)
            if lane.type == LANE_BIKE:
                marks.append(aligned(strip(xy, width if width > 0 else BIKE_LANE_WIDTH)))
                mark_kinds.append(BIKE_LANE)
                continue
            widths.append(width)
            ids.append(str(feature.id))
            lines.append(aligned(xy))
            speed = lane.speed_limit_mph * MPH
            speeds.append(speed if np.isfinite(speed) and 0 < speed < MAX_SPEED else DEFAULT_SPEED_LIMIT)
            internal.append(bool(lane.interpolating))
            succ.append([str(s) for s in lane.exit_lanes])
            left.append([_span(n) for n in lane.left_neighbors])
            right.append([_span(n) for n in lane.right_neighbors])
        elif feature.HasField("stop_sign"):
            p = _points(feature, [feature.stop_sign.position], where, "stop_sign.position")
            sx, sy = align(p[:, 0], p[:, 1], swap_xy=swap_xy, flip_y=flip_y, offset=offset)
            stops.append((float(sx[0]), float(sy[0])))
            stop_lanes.append(str(feature.stop_sign.lane[0]) if len(feature.stop_sign.lane) else None)
        elif feature.HasField("crosswalk") or feature.HasField("speed_bump"):
            is_crosswalk = feature.HasField("crosswalk")
            polygon = (feature.crosswalk if is_crosswalk else feature.speed_bump).polygon
            xy = _points(feature, polygon, where, "crosswalk.polygon" if is_crosswalk else "speed_bump.polygon")
            if len(xy) >= 3:
                marks.append(aligned(xy))
                mark_kinds.append(CROSSWALK if is_crosswalk else SPEED_BUMP)
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
        marks=marks,
        mark_kinds=mark_kinds,
        lines=drawn,
        line_kinds=drawn_kinds,
    )


def _span(neighbour) -> tuple[str, int, int, int, int]:
    return (str(neighbour.feature_id), int(neighbour.self_start_index), int(neighbour.self_end_index),
            int(neighbour.neighbor_start_index), int(neighbour.neighbor_end_index))  # fmt: skip


def signal_states(msg, road_map: DatasetMap, n_frames: int, where: str, *, swap_xy: bool, flip_y: bool,
                  offset: tuple[float, float]) -> np.ndarray | None:  # fmt: skip
    """int8[frames, S]: each frame's state of every signal-controlled lane (columns in lane id
    order; 0, unknown, where a frame does not list the lane). Sets ``road_map.signal_lanes`` and
    ``signal_stops``."""
    dynamic = msg.dynamic_map_states
    if not len(dynamic):
        return None
    if n_frames and len(dynamic) > n_frames:
        raise ReplayError(f"{where}: dynamic_map_states: expected at most one per timestamp ({n_frames}), got "
                          f"{len(dynamic)}")  # fmt: skip
    lanes: dict[int, int] = {}
    stops: dict[int, tuple[float, float]] = {}
    for state in dynamic:
        for lane_state in state.lane_states:
            lanes.setdefault(int(lane_state.lane), 0)
            if lane_state.HasField("stop_point") and int(lane_state.lane) not in stops:
                p = lane_state.stop_point
                if np.isfinite([p.x, p.y]).all():
                    stops[int(lane_state.lane)] = (p.x, p.y)
    if not lanes:
        return None
    order = sorted(lanes)
    column = {lane: k for k, lane in enumerate(order)}
    out = np.zeros((max(n_frames, len(dynamic)), len(order)), dtype=np.int8)
    for f, state in enumerate(dynamic):
        for lane_state in state.lane_states:
            code = int(lane_state.state)
            out[f, column[int(lane_state.lane)]] = code if 0 <= code <= 8 else 0
    xy = np.array([stops.get(lane, (np.nan, np.nan)) for lane in order], dtype=np.float64).reshape(-1, 2)
    road_map.signal_lanes = [str(lane) for lane in order]
    road_map.signal_stops = np.stack(align(xy[:, 0], xy[:, 1], swap_xy=swap_xy, flip_y=flip_y, offset=offset), axis=1)
    return out


def strip(centre: np.ndarray, width: float) -> np.ndarray:
    """The polygon of a band ``width`` wide around a centre polyline."""
    d = np.gradient(centre, axis=0)
    norm = np.maximum(np.hypot(d[:, 0], d[:, 1]), 1e-9)
    normal = np.stack([-d[:, 1], d[:, 0]], axis=1) / norm[:, None] * (0.5 * width)
    return np.concatenate([centre + normal, (centre - normal)[::-1]])


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
