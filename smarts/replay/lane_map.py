"""A dataset's lane graph (centre lines, successors, neighbours) compiled into a RoadMap.

Argoverse 2 and Waymo maps are lane segments, not roads. A Waymo lane's neighbour may run beside it
for part of its length only (a turn pocket beside the last 40 m, a lane that merges in): the
dataset gives the stretch of both lanes where a lane change may happen. So lanes are cut where such
stretches begin and end, and two pieces are neighbours (lanes of one road, lane 0 the rightmost)
only where the dataset names them neighbours and they run alongside each other for most of both
pieces' length (:data:`ALONGSIDE`), on the named side, going the same way; a lane change is then
possible exactly where the dataset allows it and routes follow the roads. Junction lanes (the
dataset's intersection / interpolating lanes, and lanes that cross another lane's centre line) are
marked ``internal`` and pair only with junction lanes.

``smarts.maps.assemble`` derives everything else (arc lengths, spatial grid, drivable raster,
lanepoints) exactly as for SUMO maps, so every query behaves the same on dataset maps. Stop signs,
the lanes of recorded traffic signals (connections with a signal of no fixed-time program, set by
the replay provider) and marks (crosswalks, bike lanes, speed bumps) come with the map.
"""

from __future__ import annotations

import hashlib

import numpy as np

from smarts.compiled import njit
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
ALONGSIDE = 0.8
"""Fraction of each of two lane pieces' length over which the other must run beside it for them to
be lanes of one road."""
MIN_PIECE = 2.0
"""m: a lane is not cut closer than this to its ends or another cut (the datasets' stretch ends are
a polyline point apart from lane to lane)."""
MAX_BESIDE = 2.0
"""A neighbour's centre line lies within this many half lane widths (summed) of the lane's."""
CROSSING_ANGLE = np.radians(20.0)
"""Two lanes whose centre lines cross at a larger angle, away from their ends, are junction lanes."""
JUNCTION_LANE_LENGTH = 80.0
"""m: only lanes up to this long are marked junction lanes by crossing another (a long lane through
a junction keeps its lane changes elsewhere)."""

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


def _turn(a: float, b: float) -> float:
    return abs((b - a + np.pi) % (2 * np.pi) - np.pi)


def _arc(line: np.ndarray) -> np.ndarray:
    return np.concatenate([[0.0], np.cumsum(np.hypot(*np.diff(line, axis=0).T))])


def project_on(points: np.ndarray, line: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Arc length along ``line`` of each point's nearest position and its signed lateral offset
    (positive to the left of the line's direction)."""
    a, b = line[:-1], line[1:]
    ab = b - a
    denom = np.maximum((ab * ab).sum(axis=1), 1e-12)
    ap = points[:, None, :] - a[None, :, :]
    u = np.clip((ap * ab[None]).sum(axis=2) / denom[None], 0.0, 1.0)
    closest = a[None] + u[..., None] * ab[None]
    d2 = ((points[:, None, :] - closest) ** 2).sum(axis=2)
    seg = np.argmin(d2, axis=1)
    rows = np.arange(len(points))
    s0 = _arc(line)[:-1]
    seg_len = np.sqrt(denom)
    s = s0[seg] + u[rows, seg] * seg_len[seg]
    cross = ab[seg, 0] * ap[rows, seg, 1] - ab[seg, 1] * ap[rows, seg, 0]
    return s, np.sign(cross) * np.sqrt(d2[rows, seg])


def compile_lane_map(dm: DatasetMap, content_hash: str | None = None) -> RoadMap:
    """The RoadMap of a dataset map (cached in memory by content)."""
    if content_hash is None:
        content_hash = _content_hash(dm)
    cached = _compiled.get(content_hash)
    if cached is not None:
        return cached
    usable = [i for i, line in enumerate(dm.polylines) if len(line) >= 2 and np.ptp(line, axis=0).max() > 0.05]
    if not usable:
        raise ReplayError(f"{dm.source}: the map has no lane with a usable centre line")
    index_of = {dm.lane_ids[i]: k for k, i in enumerate(usable)}
    shapes = [np.asarray(dm.polylines[i], dtype=np.float64) for i in usable]
    widths = np.array([float(dm.widths[i]) if dm.widths[i] > 0 else DEFAULT_WIDTH for i in usable])
    flagged = np.array([bool(dm.internal[i]) for i in usable])
    internal = flagged | _crossing_lanes(shapes, dm, usable, index_of, flagged)
    pairs = _neighbour_pairs(dm, usable, index_of, shapes, internal)
    pieces, piece_of = _cut(shapes, pairs)
    left = _pair_pieces(pairs, pieces, piece_of, shapes, widths)
    right: dict[int, int] = {q: p for p, q in left.items()}
    n_pieces = len(pieces)
    road_of, position, roads = _roads(n_pieces, left, right)
    ids = _piece_ids(dm, usable, pieces)
    lanes = []
    for p, (k, i0, i1) in enumerate(pieces):
        i = usable[k]
        lanes.append(
            LaneSpec(
                lane_id=ids[p],
                road_id="road_" + ids[roads[road_of[p]][0]],
                index=position[p],
                width=float(widths[k]),
                speed_limit=float(dm.speed_limits[i]) if dm.speed_limits[i] > 0 else DEFAULT_SPEED_LIMIT,
                internal=bool(internal[k]),
                shape=shapes[k][i0 : i1 + 1],
            )
        )
    # the assembler wants each road's lanes together, in index order
    order = sorted(range(n_pieces), key=lambda p: (road_of[p], position[p]))
    new_index = {old: new for new, old in enumerate(order)}
    lanes = [lanes[p] for p in order]
    links = _links(dm, usable, index_of, piece_of, new_index)
    road_map = assemble_road_map(dm.source, content_hash, lanes, sorted(set(links)), junction_shapes=dm.outlines)
    pieces_of = {dm.lane_ids[usable[k]]: [new_index[p] for p in piece_of[k]] for k in range(len(usable))}
    road_map.stop_sign_xy, road_map.stop_sign_lane = _stop_signs(dm, road_map, pieces_of)
    _signals(dm, road_map, pieces_of)
    _marks(dm, road_map)
    _compiled[content_hash] = road_map
    return road_map


def _content_hash(dm: DatasetMap) -> str:
    """Hash of everything the compiled map is built from (the in-memory cache key)."""
    h = hashlib.sha256()
    for line in [*dm.polylines, *dm.marks]:
        h.update(np.ascontiguousarray(line, dtype=np.float64).tobytes())
    h.update("\0".join(dm.lane_ids).encode())
    h.update(
        repr(
            (
                dm.successors,
                dm.left,
                dm.right,
                dm.stop_sign_lanes,
                dm.mark_kinds,
                dm.signal_lanes,
                list(np.asarray(dm.internal).tolist()),
                list(np.asarray(dm.widths).tolist()),
            )
        ).encode()
    )
    h.update(np.ascontiguousarray(dm.stop_signs, dtype=np.float64).tobytes())
    h.update(np.ascontiguousarray(dm.signal_stops, dtype=np.float64).tobytes())
    return h.hexdigest()


def _roads(n_pieces: int, left: dict[int, int], right: dict[int, int]) -> tuple[list[int], list[int], list[list[int]]]:
    """Group lane pieces into roads: chains of neighbours, walked from the rightmost piece leftwards.

    Returns each piece's road and its index in that road (0 = rightmost), and each road's pieces.
    """
    road_of = [-1] * n_pieces
    position = [0] * n_pieces
    roads: list[list[int]] = []
    for p in range(n_pieces):
        if road_of[p] >= 0:
            continue
        start, seen = p, {p}
        while right.get(start) is not None and right[start] not in seen and road_of[right[start]] < 0:
            start = right[start]
            seen.add(start)
        chain, piece = [], start
        while piece is not None and road_of[piece] < 0 and piece not in chain:
            chain.append(piece)
            road_of[piece] = len(roads)
            piece = left.get(piece)
        for i, piece in enumerate(chain):
            position[piece] = i
        roads.append(chain)
    return road_of, position, roads


def _links(
    dm: DatasetMap, usable: list[int], index_of: dict[str, int], piece_of: list[list[int]], new_index: dict[int, int]
) -> list[tuple[int, int]]:
    """Lane graph links: each lane's pieces in a row, then its last piece to each named successor's first."""
    links = []
    for k, i in enumerate(usable):
        own = piece_of[k]
        links += [(new_index[a], new_index[b]) for a, b in zip(own[:-1], own[1:])]
        for succ in dm.successors[i]:
            j = index_of.get(succ)
            if j is not None and j != k:
                links.append((new_index[own[-1]], new_index[piece_of[j][0]]))
    return links


def _neighbour_pairs(dm: DatasetMap, usable: list[int], index_of: dict[str, int], shapes: list[np.ndarray],
                     internal: np.ndarray) -> list[tuple[int, int, int, int, int, int]]:  # fmt: skip
    """(lane, left neighbour, first/last point of the lane, first/last point of the neighbour) of
    every usable neighbour stretch the dataset names (a right neighbour is named the other way
    round), once each."""
    out = set()
    for k, i in enumerate(usable):
        for side, spans in (("left", dm.left[i]), ("right", dm.right[i])):
            for other, a0, a1, b0, b1 in spans:
                j = index_of.get(other)
                if j is None or j == k or internal[j] != internal[k]:
                    continue
                n, m = len(shapes[k]) - 1, len(shapes[j]) - 1
                a0, a1 = sorted((min(max(a0, 0), n), min(max(a1, 0), n)))
                b0, b1 = sorted((min(max(b0, 0), m), min(max(b1, 0), m)))
                if a1 <= a0 or b1 <= b0:
                    continue
                if _turn(_direction(shapes[k][a0 : a1 + 1]), _direction(shapes[j][b0 : b1 + 1])) > SAME_DIRECTION:
                    continue
                # within the named stretches, only where the lanes are abreast of each other
                a0, a1 = _abreast(shapes[k], a0, a1, shapes[j][[b0, b1]])
                b0, b1 = _abreast(shapes[j], b0, b1, shapes[k][[a0, a1]])
                if a1 <= a0 or b1 <= b0:
                    continue
                out.add((k, j, a0, a1, b0, b1) if side == "left" else (j, k, b0, b1, a0, a1))
    return sorted(out)


def _abreast(line: np.ndarray, i0: int, i1: int, ends: np.ndarray) -> tuple[int, int]:
    """Points ``i0..i1`` of ``line`` narrowed to those abreast of the stretch between ``ends`` (the
    first and last point of the other lane's stretch)."""
    s = _arc(line)
    along, _ = project_on(np.asarray(ends, dtype=np.float64), line)
    lo = int(np.argmin(np.abs(s - along.min())))
    hi = int(np.argmin(np.abs(s - along.max())))
    return max(i0, lo), min(i1, hi)


def _cut(shapes: list[np.ndarray], pairs: list) -> tuple[list[tuple[int, int, int]], list[list[int]]]:
    """Pieces (lane, first point, last point) of every lane cut where its neighbour stretches begin
    and end, and each lane's pieces in driving order."""
    cuts: list[set[int]] = [set() for _ in shapes]
    for k, j, a0, a1, b0, b1 in pairs:
        cuts[k].update((a0, a1))
        cuts[j].update((b0, b1))
    pieces, piece_of = [], []
    for k, line in enumerate(shapes):
        s = _arc(line)
        kept = [0]
        for c in sorted(cuts[k]):
            if s[c] - s[kept[-1]] >= MIN_PIECE and s[-1] - s[c] >= MIN_PIECE:
                kept.append(c)
        kept.append(len(line) - 1)
        own = []
        for i0, i1 in zip(kept[:-1], kept[1:]):
            own.append(len(pieces))
            pieces.append((k, i0, i1))
        piece_of.append(own)
    return pieces, piece_of


def _pair_pieces(pairs: list, pieces: list, piece_of: list[list[int]], shapes: list[np.ndarray],
                 widths: np.ndarray) -> dict[int, int]:  # fmt: skip
    """piece -> its left neighbour piece: pieces of a named stretch that run alongside each other
    (the best pairs first, each piece paired at most once per side)."""
    candidates = []
    for k, j, a0, a1, b0, b1 in pairs:
        for p in piece_of[k]:
            _, p0, p1 = pieces[p]
            if min(p1, a1) <= max(p0, a0):
                continue
            for q in piece_of[j]:
                _, q0, q1 = pieces[q]
                if min(q1, b1) <= max(q0, b0):
                    continue
                score = _alongside(shapes[k][p0 : p1 + 1], shapes[j][q0 : q1 + 1], 0.5 * (widths[k] + widths[j]))
                if score >= ALONGSIDE:
                    candidates.append((-score, p, q))
    left: dict[int, int] = {}
    taken: set[int] = set()
    for _, p, q in sorted(candidates):
        if p not in left and q not in taken:
            left[p] = q
            taken.add(q)
    return left


def _alongside(a: np.ndarray, b: np.ndarray, beside: float) -> float:
    """How much of both polylines runs beside the other, with ``b`` on the left of ``a``: the
    smaller of the fractions of each one's evenly spaced points that lie on the proper side of the
    other between a quarter and :data:`MAX_BESIDE` half widths (``beside``) from it."""
    if _arc(a)[-1] <= 0 or _arc(b)[-1] <= 0:
        return 0.0
    _, tb = project_on(resample(b, 17), a)
    _, ta = project_on(resample(a, 17), b)

    def inside(t: np.ndarray) -> float:
        return float(((t > 0.25 * beside) & (t < MAX_BESIDE * beside)).mean())

    return min(inside(tb), inside(-ta))


def _piece_ids(dm: DatasetMap, usable: list[int], pieces: list) -> list[str]:
    """A lane that is not cut keeps its id; a cut lane's first piece keeps it and the others are
    ``<id>#2``, ``<id>#3``, ..."""
    ids, seen = [], {}
    for k, _, _ in pieces:
        lane = dm.lane_ids[usable[k]]
        seen[lane] = seen.get(lane, 0) + 1
        ids.append(lane if seen[lane] == 1 else f"{lane}#{seen[lane]}")
    return ids


def _crossing_lanes(shapes: list[np.ndarray], dm: DatasetMap, usable: list[int], index_of: dict,
                    flagged: np.ndarray) -> np.ndarray:  # fmt: skip
    """bool per usable lane: it crosses another lane's centre line at more than
    :data:`CROSSING_ANGLE`, away from both lanes' ends (lanes that meet end to end do not cross).
    Two lanes the dataset already calls junction lanes are not compared."""
    n = len(shapes)
    lengths = np.array([_arc(line)[-1] for line in shapes])
    lo = np.array([line.min(axis=0) for line in shapes])
    hi = np.array([line.max(axis=0) for line in shapes])
    near = (lo[:, None, :] <= hi[None, :, :]).all(axis=2) & (lo[None, :, :] <= hi[:, None, :]).all(axis=2)
    near &= ~np.eye(n, dtype=bool) & ~(flagged[:, None] & flagged[None, :])
    linked = np.zeros((n, n), dtype=bool)
    for k, i in enumerate(usable):
        for succ in dm.successors[i]:
            j = index_of.get(succ)
            if j is not None:
                linked[k, j] = linked[j, k] = True
    a, b = np.nonzero(np.triu(near & ~linked))
    points = np.concatenate(shapes)
    offsets = np.concatenate([[0], np.cumsum([len(line) for line in shapes])]).astype(np.int64)
    hit = _crossings(points, offsets, a.astype(np.int64), b.astype(np.int64), np.cos(CROSSING_ANGLE), 1.0)
    out = np.zeros(n, dtype=bool)
    out[a[hit]] = True
    out[b[hit]] = True
    return out & (lengths <= JUNCTION_LANE_LENGTH)


@njit(nogil=True)
def _crossings(points, offsets, a, b, max_cos, end_margin):  # pragma: no cover - compiled
    """bool per lane pair (a[k], b[k]): their centre lines cross properly at an angle whose cosine is
    below ``max_cos``, more than ``end_margin`` metres from every end of both."""
    out = np.zeros(a.shape[0], dtype=np.bool_)
    for k in range(a.shape[0]):
        la0, la1 = offsets[a[k]], offsets[a[k] + 1]
        lb0, lb1 = offsets[b[k]], offsets[b[k] + 1]
        found = False
        for i in range(la0, la1 - 1):
            if found:
                break
            px, py = points[i, 0], points[i, 1]
            rx, ry = points[i + 1, 0] - px, points[i + 1, 1] - py
            for j in range(lb0, lb1 - 1):
                qx, qy = points[j, 0], points[j, 1]
                sx, sy = points[j + 1, 0] - qx, points[j + 1, 1] - qy
                denom = rx * sy - ry * sx
                if denom == 0.0:
                    continue
                t = ((qx - px) * sy - (qy - py) * sx) / denom
                u = ((qx - px) * ry - (qy - py) * rx) / denom
                if t < 0.0 or t > 1.0 or u < 0.0 or u > 1.0:
                    continue
                nr, ns = np.sqrt(rx * rx + ry * ry), np.sqrt(sx * sx + sy * sy)
                if abs(rx * sx + ry * sy) / (nr * ns) >= max_cos:
                    continue
                xx, xy = px + t * rx, py + t * ry
                far = True
                for e in (la0, la1 - 1, lb0, lb1 - 1):
                    dx, dy = points[e, 0] - xx, points[e, 1] - xy
                    if dx * dx + dy * dy <= end_margin * end_margin:
                        far = False
                if far:
                    found = True
                    break
        out[k] = found
    return out


def _stop_signs(dm: DatasetMap, road_map: RoadMap, pieces_of: dict[str, list[int]]) -> tuple[np.ndarray, np.ndarray]:
    """Stop sign positions and the lane each controls: the piece nearest the sign of the lane the
    dataset names, else the lane nearest the sign (-1 when the named lane was dropped and none is
    near)."""
    xy = np.asarray(dm.stop_signs, dtype=np.float64).reshape(-1, 2)
    lanes = np.full(len(xy), -1, dtype=np.int32)
    named = list(dm.stop_sign_lanes) + [None] * (len(xy) - len(dm.stop_sign_lanes))
    unnamed = []
    for k, lane_id in enumerate(named):
        own = pieces_of.get(lane_id) if lane_id is not None else None
        if own:
            ends = np.array([road_map.lane_polyline(p)[-1] for p in own])
            lanes[k] = own[int(np.argmin(np.hypot(*(ends - xy[k]).T)))]
        else:
            unnamed.append(k)
    if unnamed:
        near = project(road_map, xy[unnamed])
        lanes[unnamed] = np.where(np.abs(near.t) <= MAX_STOP_SIGN_OFFSET, near.lane, -1)
    return xy, lanes


MAX_STOP_SIGN_OFFSET = 10.0
"""m: a stop sign without a named lane controls the nearest lane within this distance."""
SIGNAL_PREFIX = "signal_"
"""Signal ids of a dataset map are this prefix and the controlled lane's id."""


def _signals(dm: DatasetMap, road_map: RoadMap, pieces_of: dict[str, list[int]]) -> None:
    """One signal without a fixed-time program per recorded signal-controlled lane, with a
    connection per way through it: a lane that starts at its stop point (a junction lane) is the
    connection's junction lane, entered from each of its predecessors; a lane that ends there (an
    approach) is the incoming lane of a connection into each of its successors. A signal whose lane
    is not on the map, or that has no lane to be entered from or into, has no connection."""
    conn_from, conn_via, conn_to, conn_tls = [], [], [], []
    tls_ids = []
    for s, lane_id in enumerate(dm.signal_lanes):
        own = pieces_of.get(lane_id)
        tls_ids.append(SIGNAL_PREFIX + lane_id)
        if not own:
            continue
        stop = dm.signal_stops[s] if s < len(dm.signal_stops) else np.full(2, np.nan)
        head, tail = road_map.lane_polyline(own[0])[0], road_map.lane_polyline(own[-1])[-1]
        starts_here = not np.isfinite(stop).all() or np.hypot(*(stop - head)) <= np.hypot(*(stop - tail))
        if starts_here:
            via = own[0]
            after = road_map.successors(own[-1])
            for pred in road_map.predecessors(via).tolist():
                conn_from.append(pred)
                conn_via.append(via)
                conn_to.append(int(after[0]) if len(after) else -1)
                conn_tls.append(s)
        else:
            for succ in road_map.successors(own[-1]).tolist():
                conn_from.append(own[-1])
                conn_via.append(succ)
                nxt = road_map.successors(succ)
                conn_to.append(int(nxt[0]) if len(nxt) else -1)
                conn_tls.append(s)
    if not tls_ids:
        return
    c = len(conn_from)
    road_map.conn_from = np.array(conn_from, dtype=np.int32)
    road_map.conn_via = np.array(conn_via, dtype=np.int32)
    road_map.conn_to = np.array(conn_to, dtype=np.int32)
    road_map.conn_tls = np.array(conn_tls, dtype=np.int32)
    road_map.conn_link = np.zeros(c, dtype=np.int32)
    road_map.conn_major = np.ones(c, dtype=bool)
    road_map.conn_dir = np.full(c, "s", dtype="<U1")
    road_map.tls_ids = tls_ids
    road_map.tls_offset = np.zeros(len(tls_ids))
    road_map.tls_phase_offsets = np.zeros(len(tls_ids) + 1, dtype=np.int64)  # no programs
    road_map.tls_phase_duration = np.zeros(0)
    road_map.tls_phase_state = np.zeros(0, dtype="<U1")


def _marks(dm: DatasetMap, road_map: RoadMap) -> None:
    """Crosswalks, bike lanes and speed bumps as the map's mark polygons."""
    shapes = [np.asarray(m, dtype=np.float64).reshape(-1, 2) for m in dm.marks]
    if not shapes:
        return
    road_map.mark_kind = np.array(dm.mark_kinds, dtype=np.int8)
    road_map.mark_offsets = np.concatenate([[0], np.cumsum([len(m) for m in shapes])]).astype(np.int64)
    road_map.mark_points = np.concatenate(shapes)
