"""Junction geometry for right of way: connection paths and the conflict zones between them.

A *connection* is one way through a junction: an incoming lane, the junction lanes it passes and
the outgoing lane. Two connections conflict where the bodies of vehicles driving them could touch
(each body covered by a few discs along its path, so turning vehicles' corners count, not just
centre lines that cross): crossing paths (one must wait), paths that merge into one outgoing lane
and paths that leave the same incoming lane and separate (vehicles on them keep following each
other). The zones are computed once per map from the lane polylines, so the per-step
right-of-way check is a lookup of a few foes per connection.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from smarts.maps import RoadMap
from smarts.traffic.density import lane_exits

CROSS, MERGE, DIVERGE = 0, 1, 2
NOMINAL_LENGTH, NOMINAL_WIDTH = 5.0, 2.0
"""Vehicle size the zones are computed for (a large car); longer vehicles add their extra half
length at both ends of a zone when the zones are used."""
DISCS = 3  # a vehicle body is covered by this many discs along its length
DISC_RADIUS = float(np.hypot(NOMINAL_LENGTH / DISCS / 2, NOMINAL_WIDTH / 2))
SAMPLE_SPACING = 0.5  # metres between the vehicle positions compared along two paths
APPROACH_PIECE = 5.0  # metres of the incoming and outgoing lanes included in a connection's path
ZONE_MARGIN = 0.5  # metres added to both ends of a zone


@dataclass
class JunctionTable:
    """Connections (C of them) and their conflict zones (F of them), CSR over connections.

    Positions along a connection are metres from its start (the end of the incoming lane).
    """

    conn_from: np.ndarray  # int64[C] incoming lane
    conn_to: np.ndarray  # int64[C] outgoing lane
    conn_first: np.ndarray  # int64[C] first junction lane
    conn_major: np.ndarray  # int64[C] 1 where the connection has right of way
    conn_length: np.ndarray  # float64[C]
    conn_merge_only: np.ndarray  # int64[C] 1 where every foe merges or diverges (none crosses)
    lanes_offsets: np.ndarray  # int64[C + 1] junction lanes of each connection
    lanes: np.ndarray  # int64[...]
    conn_of_lane: np.ndarray  # int64[L] connection a junction lane belongs to, -1 elsewhere
    offset_of_lane: np.ndarray  # float64[L] position of the lane's start along its connection
    foe_offsets: np.ndarray  # int64[C + 1]
    foe: np.ndarray  # int64[F] the other connection
    foe_kind: np.ndarray  # int64[F] CROSS, MERGE or DIVERGE
    zone: np.ndarray  # float64[4, F] (in, out) on this connection, (in, out) on the foe
    """Stretches of vehicle-centre positions (from the connection start; negative before the stop
    line) in which a vehicle's body may touch one on the foe connection."""

    @property
    def num_connections(self) -> int:
        return len(self.conn_from)


def junction_table(road_map: RoadMap) -> JunctionTable:
    """Connections and conflict zones of a map (cached on the map instance)."""
    cached = road_map.__dict__.get("_junction_table")
    if cached is not None:
        return cached
    m = road_map
    exits = lane_exits(m)
    conn_from, conn_to, paths = [], [], []
    own = np.asarray(m.own_lanes(), dtype=np.int64)  # a window of a map stack: its own lanes only
    for lane in own[~m.lane_internal[own]]:
        for path, target in exits[int(lane)]:
            if path:
                conn_from.append(int(lane))
                conn_to.append(int(target))
                paths.append(path)
    n_lanes = m.num_lanes
    conn_of_lane = np.full(n_lanes, -1, dtype=np.int64)
    offset_of_lane = np.zeros(n_lanes)
    major_of = {}
    for k in range(len(m.conn_from)):
        major_of[(int(m.conn_from[k]), int(m.conn_via[k]))] = bool(m.conn_major[k])
    lengths, majors, polylines = [], [], []
    for c, path in enumerate(paths):
        offset = 0.0
        for lane in path:
            if conn_of_lane[lane] < 0:
                conn_of_lane[lane] = c
                offset_of_lane[lane] = offset
            offset += float(m.lane_length[lane])
        lengths.append(offset)
        majors.append(major_of.get((conn_from[c], path[0]), True))
        polylines.append(_joined_polyline(m, conn_from[c], path, conn_to[c]))
    lanes_offsets = np.concatenate([[0], np.cumsum([len(p) for p in paths])]).astype(np.int64)
    flat_lanes = np.array([lane for p in paths for lane in p], dtype=np.int64)

    foes: list[list[tuple[int, int, float, float, float, float]]] = [[] for _ in paths]
    if paths:
        bodies = [_body_discs(*poly) for poly in polylines]
        reach = 2.0 * DISC_RADIUS
        lo = np.array([b[1].reshape(-1, 2).min(axis=0) for b in bodies]) - reach
        hi = np.array([b[1].reshape(-1, 2).max(axis=0) for b in bodies]) + reach
        for i in range(len(paths)):
            near = np.flatnonzero(
                (lo[:, 0] <= hi[i, 0]) & (hi[:, 0] >= lo[i, 0]) & (lo[:, 1] <= hi[i, 1]) & (hi[:, 1] >= lo[i, 1])
            )
            for j in near[near > i]:
                j = int(j)
                zones = _zones(bodies[i], bodies[j])
                if zones is None:
                    continue
                zi, zj = zones
                if conn_from[i] == conn_from[j]:
                    kind = DIVERGE
                elif conn_to[i] == conn_to[j]:
                    kind = MERGE
                else:
                    kind = CROSS
                foes[i].append((j, kind, zi[0], zi[1], zj[0], zj[1]))
                foes[j].append((i, kind, zj[0], zj[1], zi[0], zi[1]))
    foe_offsets = np.concatenate([[0], np.cumsum([len(f) for f in foes])]).astype(np.int64)
    flat = [row for f in foes for row in f]
    table = JunctionTable(
        conn_from=np.array(conn_from, dtype=np.int64),
        conn_to=np.array(conn_to, dtype=np.int64),
        conn_first=np.array([p[0] for p in paths], dtype=np.int64),
        conn_major=np.array(majors, dtype=np.int64),
        conn_length=np.array(lengths, dtype=np.float64),
        conn_merge_only=np.array([all(row[1] != CROSS for row in f) for f in foes], dtype=np.int64),
        lanes_offsets=lanes_offsets,
        lanes=flat_lanes,
        conn_of_lane=conn_of_lane,
        offset_of_lane=offset_of_lane,
        foe_offsets=foe_offsets,
        foe=np.array([r[0] for r in flat], dtype=np.int64),
        foe_kind=np.array([r[1] for r in flat], dtype=np.int64),
        zone=np.array([[r[k] for r in flat] for k in range(2, 6)], dtype=np.float64).reshape(4, -1),
    )
    road_map.__dict__["_junction_table"] = table
    return table


def _joined_polyline(m: RoadMap, src: int, path: tuple[int, ...], dst: int) -> tuple[np.ndarray, float]:
    """The path's points from APPROACH_PIECE before its start to APPROACH_PIECE after its end,
    and the arc length of its start within them."""
    before = _piece(m.lane_polyline(src), -APPROACH_PIECE, None)
    pieces = [before]
    for lane in path:
        pieces.append(m.lane_polyline(lane)[1:])
    pieces.append(_piece(m.lane_polyline(dst), None, APPROACH_PIECE)[1:])
    lead = float(np.hypot(*np.diff(before, axis=0).T).sum())
    return np.concatenate(pieces), lead


def _piece(points: np.ndarray, start: float | None, end: float | None) -> np.ndarray:
    """Sub-polyline from arc length ``start`` (negative: from the end) to ``end``."""
    s = np.concatenate([[0.0], np.cumsum(np.hypot(*np.diff(points, axis=0).T))])
    a = 0.0 if start is None else (s[-1] + start if start < 0 else start)
    b = s[-1] if end is None else min(end, s[-1])
    a = min(max(a, 0.0), b)
    inner = points[(s > a) & (s < b)]
    ends = np.stack([np.interp([a, b], s, points[:, 0]), np.interp([a, b], s, points[:, 1])], axis=1)
    return np.concatenate([ends[:1], inner, ends[1:]])


def _body_discs(points: np.ndarray, lead: float) -> tuple[np.ndarray, np.ndarray]:
    """Vehicle-centre positions along a path (arc length from the connection start) and the
    discs covering a nominal vehicle body at each: (s[n], centres[n, DISCS, 2])."""
    seg = np.diff(points, axis=0)
    seg_len = np.hypot(seg[:, 0], seg[:, 1])
    keep = seg_len > 1e-9
    seg, seg_len = seg[keep], seg_len[keep]
    pts = np.concatenate([points[:1], points[1:][keep]])
    s_pts = np.concatenate([[0.0], np.cumsum(seg_len)])
    n = max(2, int(np.ceil(s_pts[-1] / SAMPLE_SPACING)) + 1)
    s = np.linspace(0.0, s_pts[-1], n)
    xy = np.stack([np.interp(s, s_pts, pts[:, 0]), np.interp(s, s_pts, pts[:, 1])], axis=1)
    k = np.clip(np.searchsorted(s_pts, s, side="right") - 1, 0, len(seg) - 1)
    direction = seg[k] / seg_len[k, None]
    offsets = (np.arange(DISCS) - (DISCS - 1) / 2) * (NOMINAL_LENGTH / DISCS)
    centres = xy[:, None, :] + offsets[None, :, None] * direction[:, None, :]
    return s - lead, centres


def _zones(a, b) -> tuple[tuple[float, float], tuple[float, float]] | None:
    """Where vehicles on paths ``a`` and ``b`` (from ``_body_discs``) can touch: the stretch of
    centre positions on each, or None."""
    s_a, discs_a = a
    s_b, discs_b = b
    diff = discs_a[:, None, :, None, :] - discs_b[None, :, None, :, :]
    touch = ((diff**2).sum(axis=-1) < (2.0 * DISC_RADIUS) ** 2).any(axis=(2, 3))  # [na, nb]
    on_a = np.flatnonzero(touch.any(axis=1))
    if on_a.size == 0:
        return None
    on_b = np.flatnonzero(touch.any(axis=0))
    zone_a = (float(s_a[on_a[0]] - ZONE_MARGIN), float(s_a[on_a[-1]] + ZONE_MARGIN))
    zone_b = (float(s_b[on_b[0]] - ZONE_MARGIN), float(s_b[on_b[-1]] + ZONE_MARGIN))
    return zone_a, zone_b
