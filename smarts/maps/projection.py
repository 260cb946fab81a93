"""Batched projection of points onto lanes: nearest lane and lane coordinates (s, t).

This runs every step for every vehicle: grid cell -> candidate segments -> per-point best
candidate, in one compiled loop over the points (a handful of numpy calls per point would cost more
than the whole loop).
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np

from smarts.compiled import njit
from smarts.maps.road_map import RoadMap
from smarts.records import declare, freeze_fields, picklable_state, view

ALIGNMENT_DISTANCE_WEIGHT = 0.02
"""Among lanes a point is on, each metre from the centre line costs as much as 1 - cos(11 deg) of
heading misalignment: heading decides between overlapping junction lanes, distance breaks ties."""
_OFF_LANE_RANK = 4.0
"""Added to off-lane candidates' squared distance so they rank after every on-lane candidate
(on-lane keys are at most 2 + weight * half width)."""

# Rows of the per-segment table, gathered for candidates with one ``take``.
_AX, _AY, _VX, _VY, _INV_LEN2, _HALF_W2, _COS, _SIN = range(8)
_FIRST, _LAST, _LANE, _S0, _LEN, _HEADING = range(8, 14)


class LaneProjection(NamedTuple):
    """Per-point result; lane is -1 (distance inf, s = t = 0) where no lane is near."""

    lane: np.ndarray  # int32[N]
    s: np.ndarray  # float64[N] arc length along the lane (extrapolated before/after its ends)
    t: np.ndarray  # float64[N] signed lateral offset, positive to the left
    lane_heading: np.ndarray  # float64[N] heading of the lane at s
    distance: np.ndarray  # float64[N] distance to the lane's centre line


class Grids(NamedTuple):
    """The projection kernel's view of one or several maps' segment grids over one segment table:
    map ``m``'s cells start at ``offsets[cell_base[m]]``, with ``ny[m]`` cells per column, its
    ``origin[m]``, inverse cell size and largest cell index (x, y). ``smarts.maps.stack``
    concatenates several maps' grids into one."""

    table: np.ndarray  # float64[14, S] per-segment rows (see the _AX... constants)
    offsets: np.ndarray  # intp[cells + 1] CSR of each cell's segments
    segs: np.ndarray  # intp[...] segment indices
    cell_base: np.ndarray  # int64[M]
    ny: np.ndarray  # int64[M]
    origin: np.ndarray  # float64[M, 2]
    inv_cell: np.ndarray  # float64[M]
    cell_max: np.ndarray  # float64[M, 2]


declare(Grids)


@njit(nogil=True)
def freeze(fields):  # pragma: no cover - compiled
    """The frozen record of this module's records (see ``smarts.records``): grids are built
    once per map (or stack) and frozen once, so a projection types one argument, not eight."""
    return freeze_fields(fields)


_ONE_MAP = np.zeros(1, dtype=np.int64)  # every point on the grids' first (only) map
_NO_HEADING = np.zeros(0)  # the kernel's heading when none is given (never written)


class _Index:
    """Arrays derived once per map for the projection (kept on the RoadMap instance): ``grids``
    and its frozen form ``frozen`` (what ``project_on_grids`` takes)."""

    def __init__(self, m: RoadMap, table: np.ndarray | None = None) -> None:
        # The grid gains an empty border of cells so clamped outside (or NaN) points find nothing.
        nx, ny = m.grid_shape
        counts = np.zeros((nx + 2, ny + 2), dtype=np.int64)
        counts[1:-1, 1:-1] = np.diff(m.grid_offsets).reshape(nx, ny)
        self.grids = Grids(
            table=table if table is not None else self._segment_table(m),
            offsets=np.concatenate([[0], np.cumsum(counts.ravel())]).astype(np.intp),
            segs=m.grid_segs.astype(np.intp),
            cell_base=np.zeros(1, dtype=np.int64),
            ny=np.array([ny + 2], dtype=np.int64),
            origin=(np.asarray(m.grid_origin, dtype=np.float64) - m.grid_cell).reshape(1, 2),
            inv_cell=np.array([1.0 / m.grid_cell]),
            cell_max=np.array([[nx + 1, ny + 1]], dtype=np.float64),
        )
        self.frozen = freeze(self.grids)

    def __getstate__(self) -> dict:
        # A frozen record does not pickle; a map that was projected still does (it is made again).
        return picklable_state(self.__dict__)

    def __setstate__(self, state: dict) -> None:
        self.__dict__.update(state)
        self.frozen = freeze(self.grids)

    @staticmethod
    def _segment_table(m: RoadMap) -> np.ndarray:
        vec = m.seg_vec
        len2 = (vec * vec).sum(axis=1)
        inv_len2 = np.divide(1.0, len2, out=np.zeros_like(len2), where=len2 > 0)
        half_w = m.lane_width[m.seg_lane] / 2
        lane_of_seg = np.arange(m.num_lanes)
        first = np.zeros(len(vec))
        last = np.zeros(len(vec))
        first[m.lane_point_offsets[:-1] - lane_of_seg] = 1.0
        last[m.lane_point_offsets[1:] - lane_of_seg - 2] = 1.0
        return np.ascontiguousarray(
            np.stack(
                [
                    m.seg_start[:, 0],
                    m.seg_start[:, 1],
                    vec[:, 0],
                    vec[:, 1],
                    inv_len2,
                    half_w * half_w,
                    np.cos(m.seg_heading),
                    np.sin(m.seg_heading),
                    first,
                    last,
                    m.seg_lane.astype(np.float64),
                    m.seg_s0,
                    m.seg_len,
                    m.seg_heading,
                ]
            )
        )


def projection_index(road_map: RoadMap) -> _Index:
    index = road_map.__dict__.get("_projection_index")
    if index is None:
        index = _Index(road_map)
        road_map.__dict__["_projection_index"] = index
    return index


def project(road_map: RoadMap, xy: np.ndarray, heading: np.ndarray | None = None) -> LaneProjection:
    """Project points ``xy[N, 2]`` onto their lanes.

    A point is *on* a lane when it is within half the lane's width of its centre line. Among the
    lanes a point is on, the one best aligned with ``heading`` wins (this separates overlapping
    junction lanes); a point on no lane takes the nearest centre line. Without ``heading`` the
    nearest centre line always wins. Points farther than ``road_map.grid_margin`` from every lane,
    and NaN positions or headings, get lane -1.
    """
    ix = road_map.__dict__.get("_projection_index") or projection_index(road_map)
    return project_on_grids(ix.frozen, xy, heading, _ONE_MAP)


def project_on_grids(
    grids: object, xy: np.ndarray, heading: np.ndarray | None, point_map: np.ndarray
) -> LaneProjection:
    """``project`` with each point ``xy[p]`` searched on the grid of map ``point_map[p]`` of
    ``grids`` (a frozen ``Grids``, see ``freeze``; ``point_map`` of one entry: that map for every
    point)."""
    xy = np.ascontiguousarray(xy, dtype=np.float64).reshape(-1, 2)
    n = xy.shape[0]
    out = LaneProjection(np.empty(n, dtype=np.int32), np.empty(n), np.empty(n), np.empty(n), np.empty(n))
    h = _NO_HEADING if heading is None else np.ascontiguousarray(heading, dtype=np.float64).reshape(-1)
    _project_kernel(grids, point_map, xy, h, *out)
    return out


@njit(nogil=True)
def _project_kernel(
    frozen_grids, point_map, xy, heading, out_lane, out_s, out_t, out_heading, out_distance
):  # pragma: no cover - compiled
    """Point ``p`` searches the grid of map ``point_map[p]`` of ``frozen_grids`` (a frozen
    ``Grids``; ``point_map[0]`` for every point when it has one entry), aligned with ``heading[p]``
    unless ``heading`` has no entries. The outputs are this call's own arrays, so they stay plain
    arguments: each call types one record and eight arrays."""
    grids = view(frozen_grids)
    use_heading = heading.shape[0] != 0
    last_map = point_map.shape[0] - 1
    for p in range(xy.shape[0]):
        h = heading[p] if use_heading else 0.0
        lane, s, t, lane_heading, distance = project_point(
            grids, point_map[min(p, last_map)], xy[p, 0], xy[p, 1], h, use_heading
        )
        out_lane[p], out_s[p], out_t[p], out_heading[p], out_distance[p] = lane, s, t, lane_heading, distance


@njit(nogil=True, inline="always")
def project_point(grids, m, x, y, heading, use_heading):  # pragma: no cover - compiled
    """``(lane, s, t, lane_heading, distance)`` of one point on map ``m`` of ``grids`` (a
    ``Grids`` tuple): the projection of ``project`` (lane -1 and distance inf where no lane is
    near). Compiled callers project their own points with it (``smarts.core.settle``)."""
    table, offsets, grid_segs = grids.table, grids.offsets, grids.segs
    origin, inv_cell, cell_max = grids.origin, grids.inv_cell, grids.cell_max
    gx = min(max((x - origin[m, 0]) * inv_cell[m], 0.0), cell_max[m, 0])  # NaN -> empty border cell
    gy = min(max((y - origin[m, 1]) * inv_cell[m], 0.0), cell_max[m, 1])
    cell = grids.cell_base[m] + int(gx) * grids.ny[m] + int(gy)
    ch = cs = 0.0
    if use_heading:
        ch, cs = math.cos(heading), math.sin(heading)
    best, best_key = -1, np.inf
    first, last = offsets[cell], offsets[cell + 1]
    if x != x or y != y or (use_heading and heading != heading):
        last = first  # NaN: no lane
    for k in range(first, last):
        seg = grid_segs[k]
        rx = x - table[_AX, seg]
        ry = y - table[_AY, seg]
        vx, vy = table[_VX, seg], table[_VY, seg]
        u = min(max((rx * vx + ry * vy) * table[_INV_LEN2, seg], 0.0), 1.0)
        dx, dy = rx - u * vx, ry - u * vy
        dist2 = dx * dx + dy * dy
        if not use_heading:
            key = dist2
        elif dist2 > table[_HALF_W2, seg]:
            key = dist2 + _OFF_LANE_RANK
        else:
            key = 1.0 - (ch * table[_COS, seg] + cs * table[_SIN, seg])
            key += ALIGNMENT_DISTANCE_WEIGHT * math.sqrt(dist2)
        if key < best_key:
            best, best_key = seg, key
    if best < 0:
        return -1, 0.0, 0.0, 0.0, np.inf
    rx = x - table[_AX, best]
    ry = y - table[_AY, best]
    vx, vy = table[_VX, best], table[_VY, best]
    raw_u = (rx * vx + ry * vy) * table[_INV_LEN2, best]
    u = min(max(raw_u, 0.0), 1.0)
    dist = math.hypot(rx - u * vx, ry - u * vy)
    # Before a lane's first point or past its last, continue the end segment's line so s keeps
    # growing and t stays the lateral offset rather than a distance to the end point.
    if (raw_u < 0.0 and table[_FIRST, best] > 0.0) or (raw_u > 1.0 and table[_LAST, best] > 0.0):
        u = raw_u
    cross = vx * ry - vy * rx
    side = 1.0 if cross > 0.0 else (-1.0 if cross < 0.0 else 0.0)
    return (
        int(table[_LANE, best]), table[_S0, best] + u * table[_LEN, best],
        side * math.hypot(rx - u * vx, ry - u * vy), table[_HEADING, best], dist,
    )  # fmt: skip
