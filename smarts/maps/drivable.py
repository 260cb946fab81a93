"""Drivable-area raster: built once per map, read in O(1) per point every step.

Off-road events need "is this point on the road surface" for every vehicle corner each step; a
boolean raster answers that with one gather instead of polygon tests.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from smarts.compiled import njit
from smarts.maps.road_map import RoadMap


def on_road(road_map: RoadMap, xy: np.ndarray) -> np.ndarray:
    """True where a point ``xy[..., 2]`` lies on the drivable surface; False outside the raster."""
    lookup = road_map.__dict__.get("_raster_lookup") or _raster_lookup(road_map)
    origin, inv_res, cell_max, width, flat = lookup
    cells = np.asarray(xy, dtype=np.float64) - origin
    cells *= inv_res
    # The raster's outermost cells are always off-road, so clamping a point outside the raster
    # onto the border answers False; fmax/fmin also send NaN to a border cell.
    np.fmax(cells, 0.0, out=cells)
    np.fmin(cells, cell_max, out=cells)
    index = cells.astype(np.intp)
    flat_index = index[..., 1] * width
    flat_index += index[..., 0]
    return flat.take(flat_index)


def raster_lookup(road_map: RoadMap) -> tuple[np.ndarray, float, np.ndarray, int, np.ndarray]:
    """(origin, 1 / resolution, largest cell index (x, y), raster width, flat raster), cached."""
    return road_map.__dict__.get("_raster_lookup") or _raster_lookup(road_map)


@njit(nogil=True, inline="always")
def on_road_at(flat, width, origin, inv_res, cell_max, x, y):  # pragma: no cover - compiled
    """``on_road`` for one point, for compiled per-step kernels (same clamping rules)."""
    cx = min(max((x - origin[0]) * inv_res, 0.0), cell_max[0])
    cy = min(max((y - origin[1]) * inv_res, 0.0), cell_max[1])
    if x != x or y != y:
        return False
    return flat[int(cy) * width + int(cx)]


def _raster_lookup(road_map: RoadMap) -> tuple[np.ndarray, float, np.ndarray, int, np.ndarray]:
    raster = np.ascontiguousarray(road_map.drivable)
    height, width = raster.shape
    lookup = (
        np.asarray(road_map.raster_origin, dtype=np.float64),
        1.0 / road_map.raster_resolution,
        np.array([width - 1, height - 1], dtype=np.float64),
        width,
        raster.reshape(-1),
    )
    road_map.__dict__["_raster_lookup"] = lookup
    return lookup


def build_drivable_raster(
    polylines: Sequence[np.ndarray],
    widths: np.ndarray,
    junction_shapes: Sequence[np.ndarray],
    resolution: float = 0.25,
    max_cells: int = 16_000_000,
) -> tuple[np.ndarray, float, np.ndarray]:
    """Rasterise lanes (segment quads + discs at vertices) and junction polygons.

    Returns (origin, resolution, raster[H, W]). The resolution is coarsened when the map is so
    large that the raster would exceed ``max_cells``, which bounds memory on city-sized maps.
    """
    from PIL import Image, ImageDraw  # only compiling a map needs PIL

    all_xy = np.concatenate([*polylines, *junction_shapes])
    pad = float(np.max(widths)) + 1.0
    lo = all_xy.min(axis=0) - pad
    hi = all_xy.max(axis=0) + pad
    extent = hi - lo

    def cells(res: float) -> int:
        return (math.ceil(extent[0] / res) + 2) * (math.ceil(extent[1] / res) + 2)

    if cells(resolution) > max_cells:
        resolution = math.sqrt(extent[0] * extent[1] / max_cells)
        while cells(resolution) > max_cells:
            resolution *= 1.01
    width = int(math.ceil(extent[0] / resolution)) + 2
    height = int(math.ceil(extent[1] / resolution)) + 2
    lo = lo - resolution  # one spare cell on every side for the off-road border

    image = Image.new("L", (width, height), 0)
    draw = ImageDraw.Draw(image)

    def to_pixels(xy: np.ndarray) -> np.ndarray:
        # Pixel (i, j) is drawn when its centre is covered; PIL puts pixel centres at integers.
        return (xy - lo) / resolution - 0.5

    # All segments of all lanes at once: a quad of the lane's width around each segment.
    a = np.concatenate([poly[:-1] for poly in polylines])
    b = np.concatenate([poly[1:] for poly in polylines])
    seg_width = np.repeat(widths, [len(poly) - 1 for poly in polylines])
    vec = b - a
    length = np.hypot(vec[:, 0], vec[:, 1])
    ok = length > 0
    a, b, vec, length, seg_width = a[ok], b[ok], vec[ok], length[ok], seg_width[ok]
    normal = np.stack([-vec[:, 1], vec[:, 0]], axis=1) * (seg_width / 2 / length)[:, None]
    quads = to_pixels(np.stack([a + normal, b + normal, b - normal, a - normal], axis=1))
    for quad in quads.reshape(-1, 8).tolist():
        draw.polygon(quad, fill=1)
    # Discs at the vertices fill the wedge gaps between quads where a lane bends, and round off
    # lane ends so a point exactly at a lane's end is on the road.
    centres = to_pixels(np.concatenate(polylines))
    radius = np.repeat(widths / 2 / resolution, [len(poly) for poly in polylines])
    boxes = np.concatenate([centres - radius[:, None], centres + radius[:, None]], axis=1)
    for box in boxes.tolist():
        draw.ellipse(box, fill=1)

    for shape in junction_shapes:
        if len(shape) >= 3:
            draw.polygon(to_pixels(shape).reshape(-1).tolist(), fill=1)

    raster = np.asarray(image, dtype=np.uint8).astype(bool)
    # Keep the border off-road: on_road clamps outside points onto it.
    raster[[0, -1], :] = False
    raster[:, [0, -1]] = False
    return lo.astype(np.float64), float(resolution), raster
