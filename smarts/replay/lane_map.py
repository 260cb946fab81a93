"""A dataset's lane graph (centre lines, successors, left/right neighbours) compiled into a RoadMap.

Argoverse 2 and Waymo maps are lane segments, not roads: roads are rebuilt here as chains of
same-direction neighbours (lane 0 the rightmost), then ``smarts.maps.assemble`` derives everything
else (arc lengths, spatial grid, drivable raster, lanepoints) exactly as for SUMO maps, so every
query behaves the same on dataset maps.
"""

from __future__ import annotations

import hashlib

import numpy as np

from smarts.core.errors import ReplayError
from smarts.maps.assemble import LaneSpec, assemble_road_map
from smarts.maps.projection import project
from smarts.maps.road_map import RoadMap
from smarts.replay.recording import DatasetMap

DEFAULT_WIDTH = 3.7
"""m: lane width where the dataset gives none (Waymo lane centres)."""
DEFAULT_SPEED_LIMIT = 13.89
"""m/s (50 km/h) where the dataset gives none."""
SAME_DIRECTION = np.pi / 2
"""A neighbour heading more than this away from a lane runs the other way: it is another road."""

_compiled: dict[str, RoadMap] = {}


def resample(line: np.ndarray, n: int) -> np.ndarray:
    """``n`` points evenly spaced along a polyline by arc length."""
    line = np.asarray(line, dtype=np.float64).reshape(-1, 2)
    if len(line) == 1:
        return np.repeat(line, n, axis=0)
    s = np.concatenate([[0.0], np.cumsum(np.hypot(*np.diff(line, axis=0).T))])
    if s[-1] <= 0:
        return np.repeat(line[:1], n, axis=0)
    t = np.linspace(0.0, s[-1], n)
    return np.stack([np.interp(t, s, line[:, 0]), np.interp(t, s, line[:, 1])], axis=1)


def centre_and_width(left: np.ndarray, right: np.ndarray) -> tuple[np.ndarray, float]:
    """A lane's centre line and mean width from its two boundaries (each in driving direction)."""
    n = max(len(left), len(right), 2)
    lft, rgt = resample(left, n), resample(right, n)
    return 0.5 * (lft + rgt), float(np.mean(np.hypot(*(lft - rgt).T)))


def _direction(line: np.ndarray) -> float:
    d = line[-1] - line[0]
    return float(np.arctan2(d[1], d[0]))


def compile_lane_map(dm: DatasetMap, content_hash: str | None = None) -> RoadMap:
    """The RoadMap of a dataset map (cached in memory by content)."""
    if content_hash is None:
        h = hashlib.sha256()
        for line in dm.polylines:
            h.update(np.ascontiguousarray(line, dtype=np.float64).tobytes())
        h.update("\0".join(dm.lane_ids).encode())
        h.update(repr((dm.successors, dm.left, dm.right, dm.stop_sign_lanes)).encode())
        h.update(np.ascontiguousarray(dm.stop_signs, dtype=np.float64).tobytes())
        content_hash = h.hexdigest()
    cached = _compiled.get(content_hash)
    if cached is not None:
        return cached
    usable = [i for i, line in enumerate(dm.polylines) if len(line) >= 2 and np.ptp(line, axis=0).max() > 0.05]
    if not usable:
        raise ReplayError(f"{dm.source}: the map has no lane with a usable centre line")
    index_of = {dm.lane_ids[i]: k for k, i in enumerate(usable)}
    heading = [_direction(np.asarray(dm.polylines[i])) for i in usable]

    def neighbour(k: int, side: list[str | None]) -> int | None:
        other = side[usable[k]]
        j = index_of.get(other) if other is not None else None
        if j is None or j == k:
            return None
        turn = abs((heading[j] - heading[k] + np.pi) % (2 * np.pi) - np.pi)
        return j if turn <= SAME_DIRECTION else None

    left = [neighbour(k, dm.left) for k in range(len(usable))]
    right = [neighbour(k, dm.right) for k in range(len(usable))]
    # roads: chains of neighbours, walked from the rightmost lane leftwards
    road_of = [-1] * len(usable)
    position = [0] * len(usable)
    roads: list[list[int]] = []
    for k in range(len(usable)):
        if road_of[k] >= 0:
            continue
        start, seen = k, {k}
        while right[start] is not None and right[start] not in seen and road_of[right[start]] < 0:
            start = right[start]
            seen.add(start)
        chain, lane = [], start
        while lane is not None and road_of[lane] < 0 and lane not in chain:
            chain.append(lane)
            road_of[lane] = len(roads)
            lane = left[lane]
        for i, lane in enumerate(chain):
            position[lane] = i
        roads.append(chain)
    lanes = []
    for k, i in enumerate(usable):
        road = roads[road_of[k]]
        road_id = "road_" + "_".join(dm.lane_ids[usable[j]] for j in road[:1])
        lanes.append(
            LaneSpec(
                lane_id=dm.lane_ids[i],
                road_id=road_id,
                index=position[k],
                width=float(dm.widths[i]) if dm.widths[i] > 0 else DEFAULT_WIDTH,
                speed_limit=float(dm.speed_limits[i]) if dm.speed_limits[i] > 0 else DEFAULT_SPEED_LIMIT,
                internal=bool(dm.internal[i]),
                shape=np.asarray(dm.polylines[i], dtype=np.float64),
            )
        )
    # the assembler wants each road's lanes together, in index order
    order = sorted(range(len(lanes)), key=lambda k: (road_of[k], position[k]))
    new_index = {old: new for new, old in enumerate(order)}
    lanes = [lanes[k] for k in order]
    links = []
    for k, i in enumerate(usable):
        for succ in dm.successors[i]:
            j = index_of.get(succ)
            if j is not None and j != k:
                links.append((new_index[k], new_index[j]))
    road_map = assemble_road_map(dm.source, content_hash, lanes, sorted(set(links)), junction_shapes=dm.outlines)
    road_map.stop_sign_xy, road_map.stop_sign_lane = _stop_signs(dm, road_map)
    _compiled[content_hash] = road_map
    return road_map


def _stop_signs(dm: DatasetMap, road_map: RoadMap) -> tuple[np.ndarray, np.ndarray]:
    """Stop sign positions and the lane each controls: the lane the dataset names, else the lane
    nearest the sign (-1 when the named lane was dropped and none is near)."""
    xy = np.asarray(dm.stop_signs, dtype=np.float64).reshape(-1, 2)
    lanes = np.full(len(xy), -1, dtype=np.int32)
    named = list(dm.stop_sign_lanes) + [None] * (len(xy) - len(dm.stop_sign_lanes))
    unnamed = []
    for k, lane_id in enumerate(named):
        index = road_map.lane_index_of.get(lane_id) if lane_id is not None else None
        if index is not None:
            lanes[k] = index
        else:
            unnamed.append(k)
    if unnamed:
        near = project(road_map, xy[unnamed])
        lanes[unnamed] = np.where(np.abs(near.t) <= MAX_STOP_SIGN_OFFSET, near.lane, -1)
    return xy, lanes


MAX_STOP_SIGN_OFFSET = 10.0
"""m: a stop sign without a named lane controls the nearest lane within this distance."""
