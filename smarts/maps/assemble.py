"""Turn per-lane geometry and lane-to-lane links into a :class:`RoadMap`.

Readers of map formats (SUMO today; dataset maps later) only extract lanes and links; everything
derived from them (arc lengths, segments, the spatial grid, the drivable raster, lanepoints) is
built here once so every format gets identical query behaviour.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from smarts.maps.drivable import build_drivable_raster
from smarts.maps.errors import MapError
from smarts.maps.road_map import RoadMap

LANEPOINT_SPACING = 1.0
"""Metres between consecutive lanepoints (waypoints are read from these)."""
GRID_CELL = 10.0
"""Side of a spatial-grid cell in metres: small enough that a cell lists few segments."""
GRID_EXTRA_MARGIN = 3.0
"""How far beyond one lane width from a centre line the grid still finds the exact nearest lane."""


@dataclass
class LaneSpec:
    """One drivable lane as read from a map file."""

    lane_id: str
    road_id: str
    index: int  # 0 = rightmost drivable lane of the road
    width: float
    speed_limit: float
    internal: bool
    shape: np.ndarray  # float64[n, 2], n >= 1, consecutive duplicates allowed
    sumo_length: float | None = None  # SUMO's ``length`` attribute; None: the shape's length


def assemble_road_map(
    source: str,
    content_hash: str,
    lanes: Sequence[LaneSpec],
    links: Sequence[tuple[int, int]],
    junction_shapes: Sequence[np.ndarray] = (),
    raster_resolution: float = 0.25,
    max_raster_cells: int = 16_000_000,
) -> RoadMap:
    """Build every array of a :class:`RoadMap`.

    ``links`` are (from lane, to lane) successor pairs; lanes must be given with their road's
    lane index (0 = rightmost) already assigned.
    """
    if not lanes:
        raise MapError(f"{source}: the map has no drivable lanes")
    num_lanes = len(lanes)
    roads = _lane_columns(lanes)
    polylines, counts, lines = _centre_lines(lanes)
    lane_width = roads["lane_width"]

    lane_left, lane_right = _neighbours(roads["lane_road"], roads["lane_index"])
    succ_offsets, succ = _csr(num_lanes, links, reverse=False)
    pred_offsets, pred = _csr(num_lanes, links, reverse=True)
    segments = _segments(lines["points"], lines["point_s"], lines["lane_point_offsets"], counts, num_lanes)

    margin = float(lane_width.max()) + GRID_EXTRA_MARGIN
    grid_origin, grid_shape, grid_offsets, grid_segs = build_segment_grid(
        segments["seg_start"], segments["seg_vec"], GRID_CELL, margin
    )

    shapes = [np.asarray(s, dtype=np.float64).reshape(-1, 2) for s in junction_shapes]
    raster_origin, resolution, drivable = build_drivable_raster(
        polylines, lane_width, shapes, raster_resolution, max_raster_cells
    )

    lp_offsets, lp_xy, lp_s, lp_heading = _lanepoints(
        lines["points"], lines["point_s"], lines["lane_point_offsets"], segments["seg_heading"], LANEPOINT_SPACING
    )

    return RoadMap(
        source=source,
        content_hash=content_hash,
        **roads,
        **lines,
        lane_left=lane_left,
        lane_right=lane_right,
        succ_offsets=succ_offsets,
        succ=succ,
        pred_offsets=pred_offsets,
        pred=pred,
        **segments,
        grid_origin=grid_origin,
        grid_cell=GRID_CELL,
        grid_shape=grid_shape,
        grid_margin=margin,
        grid_offsets=grid_offsets,
        grid_segs=grid_segs,
        raster_origin=raster_origin,
        raster_resolution=resolution,
        drivable=drivable,
        lanepoint_offsets=lp_offsets,
        lanepoints=lp_xy,
        lanepoint_s=lp_s,
        lanepoint_heading=lp_heading,
        bounds=_bounds(lines["points"], shapes, lane_width),
        junction_shapes=shapes,
    )


def _lane_columns(lanes: Sequence[LaneSpec]) -> dict:
    """Per-lane scalar columns, and the road index each lane belongs to (roads numbered in first-seen order)."""
    road_ids: list[str] = []
    road_index_of: dict[str, int] = {}
    for lane in lanes:
        if lane.road_id not in road_index_of:
            road_index_of[lane.road_id] = len(road_ids)
            road_ids.append(lane.road_id)
    return dict(
        lane_ids=[lane.lane_id for lane in lanes],
        road_ids=road_ids,
        road_index_of=road_index_of,
        lane_road=np.array([road_index_of[lane.road_id] for lane in lanes], dtype=np.int32),
        lane_index=np.array([lane.index for lane in lanes], dtype=np.int16),
        lane_width=np.array([lane.width for lane in lanes], dtype=np.float64),
        lane_speed_limit=np.array([lane.speed_limit for lane in lanes], dtype=np.float64),
        lane_internal=np.array([lane.internal for lane in lanes], dtype=bool),
    )


def _centre_lines(lanes: Sequence[LaneSpec]) -> tuple[list[np.ndarray], np.ndarray, dict]:
    """All lanes' cleaned centre lines in one point array, with arc length s restarting at 0 per lane.

    Returns the per-lane polylines (the raster draws them), the point count per lane, and the
    RoadMap columns: points, point_s, lane_point_offsets, lane_length, lane_sumo_length.
    """
    polylines = [_clean_polyline(lane.shape) for lane in lanes]
    counts = np.array([len(p) for p in polylines], dtype=np.int64)
    point_offsets = np.concatenate([[0], np.cumsum(counts)]).astype(np.int64)
    points = np.concatenate(polylines).astype(np.float64)
    step = np.zeros(len(points))
    step[1:] = np.hypot(*np.diff(points, axis=0).T)
    step[point_offsets[:-1]] = 0.0  # each lane starts at s = 0
    running = np.cumsum(step)
    point_s = running - np.repeat(running[point_offsets[:-1]], counts)
    lane_length = point_s[point_offsets[1:] - 1]
    lane_sumo_length = np.array(
        [
            lane.sumo_length if lane.sumo_length is not None else length
            for lane, length in zip(lanes, lane_length.tolist())
        ],
        dtype=np.float64,
    )
    columns = dict(
        lane_length=lane_length,
        lane_sumo_length=lane_sumo_length,
        lane_point_offsets=point_offsets,
        points=points,
        point_s=point_s,
    )
    return polylines, counts, columns


def _segments(
    points: np.ndarray, point_s: np.ndarray, point_offsets: np.ndarray, counts: np.ndarray, num_lanes: int
) -> dict:
    """Segments: every consecutive pair of points within a lane (never across two lanes)."""
    is_seg_start = np.ones(len(points), dtype=bool)
    is_seg_start[point_offsets[1:] - 1] = False
    seg_idx = np.flatnonzero(is_seg_start)
    seg_start = points[seg_idx]
    seg_vec = points[seg_idx + 1] - seg_start
    return dict(
        seg_start=seg_start,
        seg_vec=seg_vec,
        seg_len=np.hypot(seg_vec[:, 0], seg_vec[:, 1]),
        seg_heading=np.arctan2(seg_vec[:, 1], seg_vec[:, 0]),
        seg_lane=np.repeat(np.arange(num_lanes, dtype=np.int32), counts - 1),
        seg_s0=point_s[seg_idx],
    )


def _bounds(points: np.ndarray, shapes: list[np.ndarray], lane_width: np.ndarray) -> np.ndarray:
    """(x min, y min, x max, y max) of every centre line and junction shape, padded by half the widest lane."""
    all_xy = np.concatenate([points, *shapes]) if shapes else points
    pad = float(lane_width.max()) / 2
    return np.array(
        [
            all_xy[:, 0].min() - pad,
            all_xy[:, 1].min() - pad,
            all_xy[:, 0].max() + pad,
            all_xy[:, 1].max() + pad,
        ]
    )


def _clean_polyline(shape: np.ndarray) -> np.ndarray:
    """Drop repeated points so no segment has zero length; keep two points even for a dot."""
    shape = np.asarray(shape, dtype=np.float64).reshape(-1, 2)
    keep = np.ones(len(shape), dtype=bool)
    keep[1:] = np.hypot(*np.diff(shape, axis=0).T) > 1e-9
    cleaned = shape[keep]
    if len(cleaned) < 2:
        cleaned = np.vstack([cleaned[:1], cleaned[:1]])
    return cleaned


def _neighbours(lane_road: np.ndarray, lane_index: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    left = np.full(len(lane_road), -1, dtype=np.int32)
    right = np.full(len(lane_road), -1, dtype=np.int32)
    slot = {(int(r), int(i)): lane for lane, (r, i) in enumerate(zip(lane_road, lane_index))}
    for (road, index), lane in slot.items():
        left[lane] = slot.get((road, index + 1), -1)
        right[lane] = slot.get((road, index - 1), -1)
    return left, right


def _csr(n: int, links: Sequence[tuple[int, int]], reverse: bool) -> tuple[np.ndarray, np.ndarray]:
    pairs = np.array(sorted(set(links)), dtype=np.int64).reshape(-1, 2)
    if reverse:
        pairs = pairs[:, ::-1]
    pairs = pairs[np.lexsort((pairs[:, 1], pairs[:, 0]))]
    offsets = np.zeros(n + 1, dtype=np.int64)
    np.cumsum(np.bincount(pairs[:, 0], minlength=n), out=offsets[1:])
    return offsets, pairs[:, 1].astype(np.int32)


def build_segment_grid(
    seg_start: np.ndarray, seg_vec: np.ndarray, cell: float, margin: float
) -> tuple[np.ndarray, tuple[int, int], np.ndarray, np.ndarray]:
    """Uniform grid listing, per cell, every segment within ``margin`` of the cell's rectangle.

    Any point inside a cell then sees every segment closer than ``margin`` to it, so the nearest
    segment found among a cell's list is the true nearest whenever it is within ``margin``.
    """
    seg_end = seg_start + seg_vec
    lo = np.minimum(seg_start, seg_end).min(axis=0) - margin
    hi = np.maximum(seg_start, seg_end).max(axis=0) + margin
    nx, ny = (int(v) for v in np.ceil((hi - lo) / cell).astype(np.int64) + 1)
    origin = lo

    seg_lo = np.minimum(seg_start, seg_end) - margin
    seg_hi = np.maximum(seg_start, seg_end) + margin
    c_lo = np.clip(np.floor((seg_lo - origin) / cell).astype(np.int64), 0, [nx - 1, ny - 1])
    c_hi = np.clip(np.floor((seg_hi - origin) / cell).astype(np.int64), 0, [nx - 1, ny - 1])
    spans = c_hi - c_lo + 1
    per_seg = spans[:, 0] * spans[:, 1]

    cell_ids: list[np.ndarray] = []
    seg_ids: list[np.ndarray] = []
    chunk = 200_000  # bound the temporary (segment, cell) pair arrays on huge maps
    cum_pairs = np.cumsum(per_seg)
    start = 0
    while start < len(seg_start):
        done = int(cum_pairs[start - 1]) if start else 0
        stop = max(int(np.searchsorted(cum_pairs, done + chunk, side="right")), start + 1)
        segs = np.arange(start, stop)
        reps = per_seg[segs]
        pair_seg = np.repeat(segs, reps)
        local = np.arange(reps.sum()) - np.repeat(np.cumsum(reps) - reps, reps)
        span_y = np.repeat(spans[segs, 1], reps)
        cx = np.repeat(c_lo[segs, 0], reps) + local // span_y
        cy = np.repeat(c_lo[segs, 1], reps) + local % span_y
        rect_lo = origin + np.stack([cx, cy], axis=1) * cell
        dist = _segment_rect_distance(seg_start[pair_seg], seg_vec[pair_seg], rect_lo, cell)
        keep = dist <= margin
        cell_ids.append(cx[keep] * ny + cy[keep])
        seg_ids.append(pair_seg[keep])
        start = stop

    cells = np.concatenate(cell_ids)
    segs_all = np.concatenate(seg_ids).astype(np.int32)
    order = np.lexsort((segs_all, cells))
    cells, segs_all = cells[order], segs_all[order]
    offsets = np.zeros(nx * ny + 1, dtype=np.int64)
    np.cumsum(np.bincount(cells, minlength=nx * ny), out=offsets[1:])
    return origin, (nx, ny), offsets, segs_all


def _segment_rect_distance(a: np.ndarray, v: np.ndarray, rect_lo: np.ndarray, size: float) -> np.ndarray:
    """Distance between segments a + u v (u in [0, 1]) and axis-aligned squares, vectorised."""
    rect_hi = rect_lo + size
    # Liang-Barsky clipping: the segment intersects the square when the clipped range is non-empty.
    t0 = np.zeros(len(a))
    t1 = np.ones(len(a))
    hit = np.ones(len(a), dtype=bool)
    for p, q in (
        (-v[:, 0], a[:, 0] - rect_lo[:, 0]),
        (v[:, 0], rect_hi[:, 0] - a[:, 0]),
        (-v[:, 1], a[:, 1] - rect_lo[:, 1]),
        (v[:, 1], rect_hi[:, 1] - a[:, 1]),
    ):
        parallel = p == 0
        hit &= ~(parallel & (q < 0))
        with np.errstate(divide="ignore", invalid="ignore"):
            r = np.where(parallel, 0.0, q / np.where(parallel, 1.0, p))
        t0 = np.where(~parallel & (p < 0), np.maximum(t0, r), t0)
        t1 = np.where(~parallel & (p > 0), np.minimum(t1, r), t1)
    hit &= t0 <= t1

    def point_rect(p: np.ndarray) -> np.ndarray:
        d = np.maximum(np.maximum(rect_lo - p, p - rect_hi), 0.0)
        return np.hypot(d[:, 0], d[:, 1])

    def corner_seg(c: np.ndarray) -> np.ndarray:
        len2 = np.maximum((v * v).sum(axis=1), 1e-18)
        u = np.clip(((c - a) * v).sum(axis=1) / len2, 0.0, 1.0)
        d = c - (a + u[:, None] * v)
        return np.hypot(d[:, 0], d[:, 1])

    dist = np.minimum(point_rect(a), point_rect(a + v))
    for cx, cy in ((0, 0), (1, 0), (0, 1), (1, 1)):
        corner = rect_lo + np.array([cx, cy]) * size
        dist = np.minimum(dist, corner_seg(corner))
    return np.where(hit, 0.0, dist)


def _lanepoints(
    points: np.ndarray,
    point_s: np.ndarray,
    point_offsets: np.ndarray,
    seg_heading: np.ndarray,
    spacing: float,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Evenly spaced points (at most ``spacing`` apart, both ends included) along every lane."""
    num_lanes = len(point_offsets) - 1
    lane_length = point_s[point_offsets[1:] - 1]
    intervals = np.maximum(1, np.ceil(lane_length / spacing - 1e-9).astype(np.int64))
    counts = intervals + 1
    offsets = np.concatenate([[0], np.cumsum(counts)]).astype(np.int64)
    lane = np.repeat(np.arange(num_lanes), counts)
    k = np.arange(offsets[-1]) - offsets[lane]
    s = k * (lane_length / intervals)[lane]
    ends = offsets[1:] - 1
    s[ends] = lane_length  # exact end despite rounding

    # Locate each s on its lane's polyline with one global search: lanes are laid end to end.
    base = np.concatenate([[0.0], np.cumsum(lane_length + 1.0)[:-1]])
    point_lane = np.repeat(np.arange(num_lanes), np.diff(point_offsets))
    j = np.searchsorted(point_s + base[point_lane], s + base[lane], side="right") - 1
    j = np.clip(j, point_offsets[:-1][lane], point_offsets[1:][lane] - 2)
    seg = j - lane  # segment index: each earlier lane has one point more than segments
    seg_start = points[j]
    seg_vec = points[j + 1] - seg_start
    seg_len = point_s[j + 1] - point_s[j]
    frac = np.divide(s - point_s[j], seg_len, out=np.zeros_like(s), where=seg_len > 0)
    xy = seg_start + frac[:, None] * seg_vec
    return offsets, xy, s, seg_heading[seg]
