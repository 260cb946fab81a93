"""Argoverse 2 motion-forecasting scenarios: a parquet track table and a static map JSON.

A scenario folder holds ``scenario_<id>.parquet`` (one row per track per 0.1 s timestep:
``track_id``, ``object_type``, ``timestep``, ``position_x``/``position_y`` in metres,
``heading`` in radians, ``velocity_x``/``velocity_y`` in m/s, ...) and ``log_map_archive_<id>.json``
(``lane_segments`` with left and right boundaries, successors and neighbours; ``drivable_areas``).
Read with pyarrow and json; the ``av2`` package is not needed. Vehicles, buses, motorcyclists and
cyclists are replayed (the dataset gives no sizes: each type's typical box); pedestrians and static
objects are left out.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from smarts.core.errors import ReplayError
from smarts.core.vehicle_table import VEHICLE_DIMENSIONS, VehicleType
from smarts.replay.lane_map import DEFAULT_SPEED_LIMIT, centre_and_width
from smarts.replay.ngsim import align
from smarts.replay.recording import DatasetMap, Recording, from_samples

FRAME_SECONDS = 0.1
REQUIRED = ("track_id", "object_type", "timestep", "position_x", "position_y", "heading", "velocity_x", "velocity_y")
OBJECT_TYPES = {
    "vehicle": VehicleType.PASSENGER,
    "bus": VehicleType.BUS,
    "motorcyclist": VehicleType.MOTORCYCLE,
    "cyclist": VehicleType.MOTORCYCLE,
}


def scenario_files(path: str | Path) -> tuple[Path, Path]:
    """The parquet and map JSON of a scenario given as its folder or its parquet file."""
    path = Path(path)
    folder = path if path.is_dir() else path.parent
    parquet = [path] if path.is_file() else sorted(folder.glob("scenario_*.parquet"))
    maps = sorted(folder.glob("log_map_archive_*.json"))
    if len(parquet) != 1:
        raise ReplayError(f"{path}: expected one scenario_<id>.parquet in the folder, found {len(parquet)}")
    if len(maps) != 1:
        raise ReplayError(f"{folder}: expected one log_map_archive_<id>.json next to {parquet[0].name}, found {len(maps)}")
    return parquet[0], maps[0]


def read_argoverse2(
    path: str | Path,
    *,
    swap_xy: bool = False,
    flip_y: bool = False,
    offset: tuple[float, float] = (0.0, 0.0),
) -> Recording:
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
    keep = np.isin(cols["object_type"], list(OBJECT_TYPES))
    if not keep.any():
        raise ReplayError(f"{parquet}: no vehicles (object_type {', '.join(OBJECT_TYPES)})")
    vtype = np.array([OBJECT_TYPES[t] for t in cols["object_type"][keep]], dtype=np.int8)
    dims = np.array([VEHICLE_DIMENSIONS[VehicleType(int(t))][:2] for t in vtype])
    x, y = align(cols["position_x"][keep], cols["position_y"][keep], swap_xy=swap_xy, flip_y=flip_y, offset=offset)
    heading = _aligned_heading(cols["heading"][keep], swap_xy, flip_y)
    speed = np.hypot(cols["velocity_x"][keep], cols["velocity_y"][keep])
    road_map = read_map(map_json, swap_xy=swap_xy, flip_y=flip_y, offset=offset)
    return from_samples(
        str(parquet), "argoverse2", cols["track_id"][keep], cols["timestep"][keep], x, y, heading, speed,
        dims[:, 0], dims[:, 1], vtype, FRAME_SECONDS, road_map=road_map,
    )  # fmt: skip


def _aligned_heading(heading: np.ndarray, swap_xy: bool, flip_y: bool) -> np.ndarray:
    """Headings under the same swap and flip as the positions."""
    c, s = np.cos(heading), np.sin(heading)
    if swap_xy:
        c, s = s, c
    if flip_y:
        s = -s
    return np.arctan2(s, c)


def read_map(
    path: Path, *, swap_xy: bool = False, flip_y: bool = False, offset: tuple[float, float] = (0.0, 0.0)
) -> DatasetMap:
    """Lane segments and drivable areas of an Argoverse 2 map JSON."""
    try:
        data = json.loads(Path(path).read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as err:
        raise ReplayError(f"{path}: not a readable map JSON ({err})") from None
    segments = data.get("lane_segments") if isinstance(data, dict) else None
    if not isinstance(segments, dict) or not segments:
        raise ReplayError(f"{path}: lane_segments: expected a mapping of lane segment id -> segment")

    def points(seg_id: str, seg: dict, key: str) -> np.ndarray:
        value = seg.get(key)
        try:
            xy = np.array([[float(p["x"]), float(p["y"])] for p in value], dtype=np.float64)
        except (TypeError, KeyError, ValueError):
            raise ReplayError(f"{path}: lane_segments.{seg_id}.{key}: expected a list of {{x, y, z}} points") from None
        if len(xy) < 2:
            raise ReplayError(f"{path}: lane_segments.{seg_id}.{key}: expected at least 2 points, got {len(xy)}")
        return np.stack(align(xy[:, 0], xy[:, 1], swap_xy=swap_xy, flip_y=flip_y, offset=offset), axis=1)

    ids, lines, widths, internal, succ, left, right = [], [], [], [], [], [], []
    for seg_id, seg in segments.items():
        if not isinstance(seg, dict):
            raise ReplayError(f"{path}: lane_segments.{seg_id}: expected a mapping")
        if seg.get("lane_type", "VEHICLE") not in ("VEHICLE", "BUS"):
            continue  # bike lanes are not driven
        centre, width = centre_and_width(points(seg_id, seg, "left_lane_boundary"), points(seg_id, seg, "right_lane_boundary"))
        ids.append(str(seg.get("id", seg_id)))
        lines.append(centre)
        widths.append(width)
        internal.append(bool(seg.get("is_intersection", False)))
        succ.append([str(s) for s in seg.get("successors") or []])
        left.append(None if seg.get("left_neighbor_id") is None else str(seg["left_neighbor_id"]))
        right.append(None if seg.get("right_neighbor_id") is None else str(seg["right_neighbor_id"]))
    outlines = []
    for area_id, area in (data.get("drivable_areas") or {}).items():
        try:
            xy = np.array([[float(p["x"]), float(p["y"])] for p in area["area_boundary"]], dtype=np.float64)
        except (TypeError, KeyError, ValueError):
            raise ReplayError(f"{path}: drivable_areas.{area_id}.area_boundary: expected a list of {{x, y, z}} points") from None
        if len(xy) >= 3:
            outlines.append(np.stack(align(xy[:, 0], xy[:, 1], swap_xy=swap_xy, flip_y=flip_y, offset=offset), axis=1))
    return DatasetMap(
        source=str(path),
        lane_ids=ids,
        polylines=lines,
        widths=np.array(widths),
        speed_limits=np.full(len(ids), DEFAULT_SPEED_LIMIT),
        internal=np.array(internal, dtype=bool),
        successors=succ,
        left=left,
        right=right,
        outlines=outlines,
    )
