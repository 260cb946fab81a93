"""Distance fields over the map's drivable raster, built once per map for the 2D sensors.

Rasters and lidar sample the map at arbitrary points every step. Two fields on the drivable
raster's grid make those samples O(1):
- ``road_clearance``: for each on-road cell, the distance (in cells) to the nearest off-road cell;
  0 off the road. A lidar ray can jump that far without crossing a road edge (sphere tracing).
- ``lane_distance``: the distance (in cells) to the nearest lane centre line, so a raster of any
  resolution draws lines about one pixel wide.
Both are uint8 (clipped at 255 cells), which bounds their memory to that of the raster itself.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import NamedTuple

import numpy as np

from smarts.maps.drivable import raster_lookup
from smarts.maps.road_map import RoadMap

FIELD_MAX = 255


@dataclass(frozen=True)
class MapFields:
    origin: np.ndarray  # float64[2] map position of the corner of cell (0, 0)
    inv_res: float  # cells per metre
    resolution: float  # metres per cell
    cell_max: np.ndarray  # float64[2] largest cell index (x, y)
    width: int  # cells per raster row
    drivable: np.ndarray  # bool[H * W], row-major (y, x)
    road_clearance: np.ndarray  # uint8[H * W]
    lane_distance: np.ndarray  # uint8[H * W]


class CellGrid(NamedTuple):
    """One per-cell field of a map with the grid it lies on, as a kernel reads it: cell (cx, cy)
    of point (x, y) is ``(x, y) - origin`` times ``inv_res``, clamped to ``cell_max``, and its
    value ``cells[cy * width + cx]``."""

    origin: np.ndarray
    inv_res: float
    cell_max: np.ndarray
    width: int
    cells: np.ndarray


def cell_grid(fields: MapFields, cells: np.ndarray) -> CellGrid:
    """``cells`` (one of ``fields``' arrays, or one made on its grid) with that grid."""
    return CellGrid(fields.origin, float(fields.inv_res), fields.cell_max, int(fields.width), cells)


def map_fields(road_map: RoadMap) -> MapFields:
    """The fields of ``road_map``, computed at first use and cached on the map object."""
    cached = road_map.__dict__.get("_sensor_fields")
    if cached is None:
        cached = _build(road_map)
        road_map.__dict__["_sensor_fields"] = cached
    return cached


ON_ROAD, ON_LANE_LINE = 1, 2


def raster_codes(road_map: RoadMap, lane_cells: float) -> np.ndarray:
    """uint8[H * W] per map cell: ``ON_ROAD`` on the road, plus ``ON_LANE_LINE`` where it lies
    within ``lane_cells`` of a lane centre line; made once per map and line width, so a raster
    pixel costs one lookup instead of two."""
    codes = road_map.__dict__.setdefault("_raster_codes", {})
    found = codes.get(lane_cells)
    if found is None:
        f = map_fields(road_map)
        on_road = f.drivable.astype(np.uint8)
        found = on_road * ON_ROAD | (on_road & (f.lane_distance <= lane_cells)).astype(np.uint8) * ON_LANE_LINE
        codes[lane_cells] = found
    return found


def _build(road_map: RoadMap) -> MapFields:
    from scipy.ndimage import (
        distance_transform_edt,  # only maps used by 2D sensors need it
    )

    origin, inv_res, cell_max, width, flat = raster_lookup(road_map)
    drivable = np.ascontiguousarray(road_map.drivable)
    clearance = distance_transform_edt(drivable)
    lines = _lane_line_cells(road_map, drivable.shape, origin, inv_res)
    to_line = distance_transform_edt(~lines) if lines.any() else np.full(drivable.shape, FIELD_MAX)
    return MapFields(
        origin=origin,
        inv_res=inv_res,
        resolution=1.0 / inv_res,
        cell_max=cell_max,
        width=width,
        drivable=flat,
        road_clearance=_to_uint8(clearance),
        lane_distance=_to_uint8(to_line),
    )


def _to_uint8(distance: np.ndarray) -> np.ndarray:
    # Floor keeps clearance a lower bound, which sphere tracing relies on.
    return np.minimum(np.floor(distance), FIELD_MAX).astype(np.uint8).reshape(-1)


def _lane_line_cells(road_map: RoadMap, shape: tuple[int, int], origin: np.ndarray, inv_res: float) -> np.ndarray:
    """Cells crossed by the centre lines of normal (non-junction) lanes, sampled every 1/3 cell."""
    lines = np.zeros(shape, dtype=bool)
    normal = ~road_map.lane_internal[road_map.seg_lane]
    start, vec, length = road_map.seg_start[normal], road_map.seg_vec[normal], road_map.seg_len[normal]
    if start.shape[0] == 0:
        return lines
    samples = np.maximum(np.ceil(length * inv_res * 3.0).astype(np.int64), 1) + 1
    seg = np.repeat(np.arange(start.shape[0]), samples)
    first = np.concatenate([[0], np.cumsum(samples)[:-1]])
    frac = (np.arange(seg.shape[0]) - np.repeat(first, samples)) / np.repeat(samples - 1, samples).clip(min=1)
    pts = start[seg] + vec[seg] * frac[:, None]
    cells = np.floor((pts - origin) * inv_res).astype(np.int64)
    ok = (cells[:, 0] >= 0) & (cells[:, 0] < shape[1]) & (cells[:, 1] >= 0) & (cells[:, 1] < shape[0])
    lines[cells[ok, 1], cells[ok, 0]] = True
    return lines
