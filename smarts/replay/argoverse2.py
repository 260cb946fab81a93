"""Argoverse 2 motion-forecasting scenarios: a parquet track table and a static map JSON.

A scenario folder holds ``scenario_<id>.parquet`` (one row per track per 0.1 s timestep:
``track_id``, ``object_type``, ``timestep``, ``position_x``/``position_y`` in metres,
``heading`` in radians, ``velocity_x``/``velocity_y`` in m/s, ...) and ``log_map_archive_<id>.json``
(``lane_segments`` with left and right boundaries and their mark types, successors and neighbours;
``drivable_areas``; ``pedestrian_crossings``). Read with pyarrow and json; the ``av2`` package is not
needed. Vehicles, buses, motorcyclists, cyclists (and riderless bicycles) and pedestrians are
replayed as their own kinds; the dataset gives no box sizes, so each kind has its typical box
(:data:`TYPICAL_SIZE`). Static, background, construction and unknown objects are left out. Bike lanes
and crosswalks join the map as marks; lane segments whose neighbours the file names are neighbours
over their whole length (Argoverse 2 cuts segments where neighbours change).
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from smarts.core.errors import ReplayError
from smarts.replay.lane_map import DEFAULT_SPEED_LIMIT, centre_and_width
from smarts.replay.ngsim import align, sniff
from smarts.replay.recording import (
    BIKE_LANE,
    CROSSWALK,
    MAX_COORDINATE,
    MAX_SPEED,
    DatasetMap,
    ObjectKind,
    Recording,
    check_values,
    from_samples,
    full_span,
    table_type,
)

FRAME_SECONDS = 0.1
EGO_ID = "AV"
"""The track id of the vehicle that recorded the scenario."""
REQUIRED = ("track_id", "object_type", "timestep", "position_x", "position_y", "heading", "velocity_x", "velocity_y")
OBJECT_KINDS = {
    "vehicle": ObjectKind.PASSENGER,
    "bus": ObjectKind.BUS,
    "motorcyclist": ObjectKind.MOTORCYCLE,
    "cyclist": ObjectKind.CYCLIST,
    "riderless_bicycle": ObjectKind.CYCLIST,
    "pedestrian": ObjectKind.PEDESTRIAN,
}
TYPICAL_SIZE = {
    ObjectKind.PASSENGER: (4.6, 1.9),
    ObjectKind.BUS: (12.0, 2.55),
    ObjectKind.TRUCK: (10.0, 2.5),
    ObjectKind.MOTORCYCLE: (2.2, 0.8),
    ObjectKind.CYCLIST: (1.8, 0.7),
    ObjectKind.PEDESTRIAN: (0.5, 0.5),
}
"""m: length and width of each kind's box (Argoverse 2 records no sizes)."""
MARK_TYPES = {"DASHED_WHITE": "dashed_white", "SOLID_WHITE": "solid_white", "DOUBLE_SOLID_WHITE": "solid_white",
              "DASHED_YELLOW": "dashed_yellow", "SOLID_YELLOW": "solid_yellow", "DOUBLE_SOLID_YELLOW": "double_yellow",
              "DOUBLE_DASH_YELLOW": "double_yellow", "DASH_SOLID_YELLOW": "double_yellow",
              "SOLID_DASH_YELLOW": "double_yellow", "DOUBLE_DASH_WHITE": "dashed_white",
              "DASH_SOLID_WHITE": "solid_white", "SOLID_DASH_WHITE": "solid_white"}  # fmt: skip
"""Lane mark types -> the kind a picture draws (``recording.LINE_KINDS``); NONE and unknown marks are
not drawn."""


def scenario_files(path: str | Path) -> tuple[Path, Path]:
    """The parquet and map JSON of a scenario given as its folder or its parquet file."""
    path = Path(path)
    if not path.exists():
        raise ReplayError(f"{path}: argoverse2 recording does not exist")
    folder = path if path.is_dir() else path.parent
    parquet = [path] if path.is_file() else sorted(folder.glob("scenario_*.parquet"))
    maps = sorted(folder.glob("log_map_archive_*.json"))
    if len(parquet) != 1:
        raise ReplayError(f"{path}: expected one scenario_<id>.parquet in the folder, found {len(parquet)}")
    if path.is_file():
        with open(path, "rb") as f:
            kind = sniff(f.read(16))
        if kind not in ("parquet", None):
            hint = {"tfrecord": " (Waymo Open Motion scenarios are read with --format waymo)",
                    "text": " (NGSIM trajectories are read with --format ngsim)"}.get(kind, "")  # fmt: skip
            raise ReplayError(f"{path}: is a {kind} file, not an Argoverse 2 scenario parquet{hint}")
    if len(maps) != 1:
        raise ReplayError(
            f"{folder}: expected one log_map_archive_<id>.json next to {parquet[0].name}, found {len(maps)}"
        )
    return parquet[0], maps[0]


def read_argoverse2(
    path: str | Path,
    *,
    swap_xy: bool = False,
    flip_y: bool = False,
    offset: tuple[float, float] = (0.0, 0.0),
) -> Recording:
    """The tracks and map of an Argoverse 2 scenario (its folder or its parquet file)."""
    import pyarrow as pa
    import pyarrow.parquet as pq

    parquet, map_json = scenario_files(path)
    try:
        schema = pq.read_schema(parquet)
    except (pa.ArrowInvalid, OSError) as err:
        raise ReplayError(f"{parquet}: not a readable parquet file ({err})") from None
    missing = [c for c in REQUIRED if c not in schema.names]
    if missing:
        raise ReplayError(f"{parquet}: missing column(s) {', '.join(missing)}; the file has: {', '.join(schema.names)}")
    try:
        table = pq.read_table(parquet, columns=list(REQUIRED))
    except (pa.ArrowInvalid, OSError) as err:
        raise ReplayError(f"{parquet}: {err}") from None
    cols = {}
    for name in REQUIRED:
        column = table.column(name)
        if column.null_count:
            row = int(np.flatnonzero(column.is_null().to_numpy(zero_copy_only=False))[0])
            raise ReplayError(f"{parquet}: column {name}: empty value in row {row + 1}")
        if name in ("track_id", "object_type"):
            cols[name] = np.asarray(column.cast(pa.string()).to_pylist(), dtype=str)
        else:
            try:
                cols[name] = column.to_numpy().astype(np.float64 if name != "timestep" else np.int64)
            except (pa.ArrowInvalid, ValueError, TypeError):
                raise ReplayError(f"{parquet}: column {name}: expected numbers, got {column.type}") from None
    keep = np.isin(cols["object_type"], list(OBJECT_KINDS))
    if not keep.any():
        raise ReplayError(f"{parquet}: no road users (object_type {', '.join(OBJECT_KINDS)})")
    rows = np.flatnonzero(keep) + 1
    for name, bound in (("position_x", MAX_COORDINATE), ("position_y", MAX_COORDINATE), ("heading", None),
                        ("velocity_x", MAX_SPEED), ("velocity_y", MAX_SPEED)):  # fmt: skip
        check_values(str(parquet), name, cols[name][keep], where="row", bound=bound, rows=rows)
    skipped = {}
    for tid, kind in zip(cols["track_id"][~keep].tolist(), cols["object_type"][~keep].tolist()):
        skipped.setdefault(tid, f"an object of type {kind}")
    kind = np.array([OBJECT_KINDS[t] for t in cols["object_type"][keep]], dtype=np.int8)
    sizes = np.array([TYPICAL_SIZE[ObjectKind(k)] for k in range(len(ObjectKind))])[kind]
    vtype = np.array([int(table_type(k)) for k in range(len(ObjectKind))], np.int8)[kind]
    x, y = align(cols["position_x"][keep], cols["position_y"][keep], swap_xy=swap_xy, flip_y=flip_y, offset=offset)
    heading = aligned_heading(cols["heading"][keep], swap_xy, flip_y)
    speed = np.hypot(cols["velocity_x"][keep], cols["velocity_y"][keep])
    road_map = read_map(map_json, swap_xy=swap_xy, flip_y=flip_y, offset=offset)
    rec = from_samples(
        str(parquet), "argoverse2", cols["track_id"][keep], cols["timestep"][keep], x, y, heading, speed,
        sizes[:, 0], sizes[:, 1], vtype, FRAME_SECONDS, road_map=road_map, kind=kind, skipped=skipped,
    )  # fmt: skip
    rec.ego = EGO_ID if EGO_ID in rec.index_of else None
    return rec


def aligned_heading(heading: np.ndarray, swap_xy: bool, flip_y: bool) -> np.ndarray:
    """Headings under the same swap and flip as the positions."""
    c, s = np.cos(heading), np.sin(heading)
    if swap_xy:
        c, s = s, c
    if flip_y:
        s = -s
    return np.arctan2(s, c)


def _items(data: dict, key: str, path: Path) -> list[tuple[str, object]]:
    """(id, entry) of a map section written as a mapping of id -> entry or as a list of entries."""
    value = data.get(key)
    if value is None:
        return []
    if isinstance(value, dict):
        return [(str(k), v) for k, v in value.items()]
    if isinstance(value, list):
        return [(str(v.get("id", i)) if isinstance(v, dict) else str(i), v) for i, v in enumerate(value)]
    raise ReplayError(
        f"{path}: {key}: expected a mapping of id -> entry (or a list of entries), got {type(value).__name__}"
    )


def read_map(
    path: Path, *, swap_xy: bool = False, flip_y: bool = False, offset: tuple[float, float] = (0.0, 0.0)
) -> DatasetMap:
    """Lane segments, drivable areas, crosswalks and bike lanes of an Argoverse 2 map JSON."""
    try:
        data = json.loads(Path(path).read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as err:
        raise ReplayError(f"{path}: not a readable map JSON ({err})") from None
    if not isinstance(data, dict):
        raise ReplayError(f"{path}: expected a mapping with lane_segments at the top level, got {type(data).__name__}")
    segments = _items(data, "lane_segments", path)
    if not segments:
        raise ReplayError(f"{path}: lane_segments: expected a mapping of lane segment id -> segment")
    reader = _MapReader(path, swap_xy, flip_y, offset)
    reader.read_lanes(segments)
    reader.read_areas(_items(data, "drivable_areas", path))
    reader.read_crossings(_items(data, "pedestrian_crossings", path))
    ids = reader.ids
    points_of = {lane: len(line) for lane, line in zip(ids, reader.centres)}

    def spans(lane: str, other: str | None) -> list[tuple[str, int, int, int, int]]:
        if other is None or other not in points_of:
            return []
        return [full_span(points_of[lane], other, points_of[other])]

    return DatasetMap(
        source=str(path),
        lane_ids=ids,
        polylines=reader.centres,
        widths=np.array(reader.widths),
        speed_limits=np.full(len(ids), DEFAULT_SPEED_LIMIT),
        internal=np.array(reader.internal, dtype=bool),
        successors=reader.succ,
        left=[spans(lane, other) for lane, other in zip(ids, reader.left_id)],
        right=[spans(lane, other) for lane, other in zip(ids, reader.right_id)],
        outlines=reader.outlines,
        marks=reader.marks,
        mark_kinds=reader.mark_kinds,
        lines=reader.drawn,
        line_kinds=reader.drawn_kinds,
    )


class _MapReader:
    """Collects one map file's lanes, areas and marks, every point aligned the same way and
    every error naming the file and the entry."""

    def __init__(self, path: Path, swap_xy: bool, flip_y: bool, offset: tuple[float, float]):
        self.path, self.swap_xy, self.flip_y, self.offset = path, swap_xy, flip_y, offset
        self.ids: list[str] = []
        self.centres: list[np.ndarray] = []
        self.widths: list[np.ndarray] = []
        self.internal: list[bool] = []
        self.succ: list[list[str]] = []
        self.left_id: list[str | None] = []
        self.right_id: list[str | None] = []
        self.outlines: list[np.ndarray] = []
        self.marks: list[np.ndarray] = []  # filled areas: bike lanes, crosswalks
        self.mark_kinds: list[int] = []
        self.drawn: list[np.ndarray] = []  # painted lines and area edges
        self.drawn_kinds: list[str] = []

    def points(self, where: str, value) -> np.ndarray:
        """A list of {x, y, z} points as aligned (x, y) rows; every point finite and within range."""
        path = self.path
        try:
            xy = np.array([[float(p["x"]), float(p["y"])] for p in value], dtype=np.float64).reshape(-1, 2)
        except (TypeError, KeyError, ValueError):
            raise ReplayError(f"{path}: {where}: expected a list of {{x, y, z}} points") from None
        bad = ~np.isfinite(xy).all(axis=1) | (np.abs(xy) > MAX_COORDINATE).any(axis=1)
        if bad.any():
            k = int(np.flatnonzero(bad)[0])
            raise ReplayError(f"{path}: {where}[{k}]: expected a finite position, got ({xy[k, 0]:g}, {xy[k, 1]:g})")
        return np.stack(align(xy[:, 0], xy[:, 1], swap_xy=self.swap_xy, flip_y=self.flip_y, offset=self.offset), axis=1)

    def boundary(self, seg_id: str, seg: dict, key: str) -> np.ndarray:
        """A lane segment's left or right boundary: at least two points."""
        xy = self.points(f"lane_segments.{seg_id}.{key}", seg.get(key))
        if len(xy) < 2:
            raise ReplayError(f"{self.path}: lane_segments.{seg_id}.{key}: expected at least 2 points, got {len(xy)}")
        return xy

    def read_lanes(self, segments: list[tuple[str, object]]) -> None:
        """Vehicle and bus lanes become lanes (centre line between the boundaries); bike lanes become marks."""
        for seg_id, seg in segments:
            if not isinstance(seg, dict):
                raise ReplayError(f"{self.path}: lane_segments.{seg_id}: expected a mapping")
            left = self.boundary(seg_id, seg, "left_lane_boundary")
            right = self.boundary(seg_id, seg, "right_lane_boundary")
            for xy, key in ((left, "left_lane_mark_type"), (right, "right_lane_mark_type")):
                kind = MARK_TYPES.get(str(seg.get(key, "")))
                if kind is not None:
                    self.drawn.append(xy)
                    self.drawn_kinds.append(kind)
            if seg.get("lane_type", "VEHICLE") == "BIKE":
                self.marks.append(np.concatenate([left, right[::-1]]))
                self.mark_kinds.append(BIKE_LANE)
                continue
            if seg.get("lane_type", "VEHICLE") not in ("VEHICLE", "BUS"):
                continue
            centre, width = centre_and_width(left, right)
            self.ids.append(str(seg.get("id", seg_id)))
            self.centres.append(centre)
            self.widths.append(width)
            self.internal.append(bool(seg.get("is_intersection", False)))
            self.succ.append([str(s) for s in seg.get("successors") or []])
            self.left_id.append(None if seg.get("left_neighbor_id") is None else str(seg["left_neighbor_id"]))
            self.right_id.append(None if seg.get("right_neighbor_id") is None else str(seg["right_neighbor_id"]))

    def read_areas(self, areas: list[tuple[str, object]]) -> None:
        """Drivable area outlines (with at least 3 points), also drawn as closed edges."""
        for area_id, area in areas:
            if not isinstance(area, dict):
                raise ReplayError(f"{self.path}: drivable_areas.{area_id}: expected a mapping with area_boundary")
            xy = self.points(f"drivable_areas.{area_id}.area_boundary", area.get("area_boundary"))
            if len(xy) >= 3:
                self.outlines.append(xy)
                self.drawn.append(np.concatenate([xy, xy[:1]]))
                self.drawn_kinds.append("edge")

    def read_crossings(self, crossings: list[tuple[str, object]]) -> None:
        """Crosswalks: the area between their two edges."""
        for cross_id, cross in crossings:
            if not isinstance(cross, dict):
                raise ReplayError(
                    f"{self.path}: pedestrian_crossings.{cross_id}: expected a mapping with edge1 and edge2"
                )
            e1 = self.points(f"pedestrian_crossings.{cross_id}.edge1", cross.get("edge1"))
            e2 = self.points(f"pedestrian_crossings.{cross_id}.edge2", cross.get("edge2"))
            if len(e1) >= 2 and len(e2) >= 2:
                self.marks.append(np.concatenate([e1, e2[::-1]]))
                self.mark_kinds.append(CROSSWALK)
