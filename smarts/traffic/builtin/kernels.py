"""Compiled per-step kernels of the built-in traffic model.

One step is two calls: ``build_occupancy`` sorts every road user (own vehicles, agents, other
providers' rows) into per-lane lists ordered by arc length, and ``step_vehicles`` decides each own
vehicle's acceleration and lane change from those lists (pass 1, all from the same start-of-step
state), then moves every vehicle and writes its pose into the vehicle table (pass 2).

Per vehicle, pass 1 does: IDM car following behind the nearest road user ahead on the vehicle's
own route (looking through lane ends into the route's next lanes); stop lines of red signals;
right of way at junctions (see ``junctions``): waiting at the stop line for foes with priority
whose passage overlaps in time, and following vehicles ahead on a merging or diverging path;
MOBIL lane changes (incentive with politeness and threshold, safety for the new follower) plus
the changes the route needs. Drivers who have waited a while (at a merge, or to change lanes
before their lane ends) get room: others slow down for them, and they accept harder braking
from others, so queues zip in rather than lock up. A hard limit keeps every move shorter than
the gap to the vehicle ahead, so vehicles never drive into each other even when braking would
not be enough.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np

from smarts.compiled import njit
from smarts.core.vehicle_table import COLUMN
from smarts.records import declare, freeze_fields
from smarts.traffic.builtin.junctions import NOMINAL_LENGTH

# --- per-row float state st[k, row]
S, LAT, LAT0, LC_PROG, COOL, FACTOR, WAIT = range(7)
NUM_FLOAT_STATE = 7
# --- per-row int state si[k, row]
SLOT, PREV_LANE, LC_LANE, LC_FROM = range(4)
NUM_INT_STATE = 4
# --- per-row driver parameters pa[k, row]
ACCEL, DECEL, EMERG, TAU, MIN_GAP, MAX_SPEED, POLITE, THRESH, KEEP_RIGHT = range(9)
NUM_PARAMS = 9
# --- per-lane floats lane_f[k, lane]
LEN, WIDTH, SPEED_LIMIT, INTERNAL = range(4)
# --- slots slot_int[k, slot]
S_LANE, S_NEXT, S_LEFT, S_RIGHT, S_DIR = range(5)
NEXT_NONE, NEXT_ARRIVE = -1, -2
# --- connections conn_int[k, c]
C_FROM, C_TO, C_FIRST, C_MAJOR, C_MERGE_ONLY = range(5)
CROSS, MERGE, DIVERGE = 0, 1, 2
NOMINAL_HALF = 0.5 * NOMINAL_LENGTH  # conflict zones hold for this half length; longer add the rest
# --- occupancy entry kinds
PRIMARY, DUPLICATE, OVERHANG = 0, 1, 2
# --- signal colours (smarts.traffic.signals)
RED, YELLOW = 1, 2

_X, _Y, _H = COLUMN["x"], COLUMN["y"], COLUMN["heading"]
_V, _A, _J = COLUMN["speed"], COLUMN["accel"], COLUMN["jerk"]
_YAW, _LATA = COLUMN["yaw_rate"], COLUMN["lat_accel"]
_LENGTH, _WIDTH = COLUMN["length"], COLUMN["width"]

LC_DURATION = 3.0  # s for the sideways move of a lane change
LC_COOLDOWN = 2.0  # s after a lane change before a discretionary one
WALL_MIN_GAP = 1.0  # m kept before stop lines and lane ends
CONFLICT_MARGIN = 1.0  # s between two vehicles' passages through a conflict zone
APPROACH_RANGE = 150.0  # m before a junction within which approaching foes count
MIN_CHANGE_ROOM = 10.0  # m of lane left that a discretionary lane change needs
SAFE_GAP = 0.5  # m: smallest gap to the new leader and follower a lane change accepts
B_SAFE_DISCRETIONARY = 3.0  # m/s^2 the new follower may have to brake for a free lane change
B_SAFE_PREFERRED = 2.0  # ... for a change towards the route's preferred lane
KEEP_RIGHT_BIAS = 0.3
"""m/s^2 per unit of lc_keep_right favouring changes to the right; above the default threshold,
so a free lane on the right is taken."""
FOLLOWER_LOOKBACK = 80.0  # m searched behind a lane change spot for the new follower
FOLLOWER_STACK = 32  # lanes a follower search keeps pending (branching predecessors)
GUARD_MARGIN = 0.2  # m a move always leaves to the road user ahead
COURTESY_WAIT = 3.0  # s a vehicle waits to merge or change lanes before others make room
IMPATIENCE_TIME = 10.0
"""s of waiting over which the braking a driver accepts to impose on others grows from
comfortable to twice that (so queues at merges and lane ends zip in instead of waiting forever)."""
IDM_DELTA = 4.0
INF = 1e9


# ----------------------------------------------------------------------------- records
class LaneGraph(NamedTuple):
    """The map's lanes as the driver model reads them (the same for every set of providers: one
    map, or one stack of maps)."""

    lane_f: np.ndarray  # float64[4, L] rows LEN, WIDTH, SPEED_LIMIT, INTERNAL
    lane_lr: np.ndarray  # int64[2, L] neighbour to the left (row 0) and right (row 1), -1 none
    pred_off: np.ndarray  # int64[L + 1] CSR of each lane's predecessors
    pred: np.ndarray  # int64[E]
    point_off: np.ndarray  # int64[L + 1] CSR of each lane's centre-line points
    point_s: np.ndarray  # float64[P] arc length of each point within its lane
    points: np.ndarray  # float64[P, 2]
    seg_heading: np.ndarray  # float64[P - L] heading of each segment (segment k of lane l: k - l)


class Routes(NamedTuple):
    """The route slots and junction tables of one set of providers (``routes``, ``junctions``)."""

    slot_int: np.ndarray  # int64[5, slots] rows S_LANE, S_NEXT, S_LEFT, S_RIGHT, S_DIR
    slot_cost: np.ndarray  # float64[slots] lane changes still needed from each slot
    conn_int: np.ndarray  # int64[5, C] rows C_FROM, C_TO, C_FIRST, C_MAJOR, C_MERGE_ONLY
    conn_len: np.ndarray  # float64[C]
    clanes_off: np.ndarray  # int64[C + 1] CSR of each connection's junction lanes
    clanes: np.ndarray  # int64[...]
    conn_of_lane: np.ndarray  # int64[L] connection of a junction lane, -1 elsewhere
    offset_of_lane: np.ndarray  # float64[L] position of the lane's start along its connection
    foe_off: np.ndarray  # int64[C + 1] CSR of each connection's conflict zones
    foe: np.ndarray  # int64[F] the other connection
    foe_kind: np.ndarray  # int64[F] CROSS, MERGE or DIVERGE
    zone: np.ndarray  # float64[4, F] (in, out) on this connection, (in, out) on the foe


class RouteSets(NamedTuple):
    """The ``Routes`` of several sets of providers: each table concatenated along its last axis
    over the sets (``tables``) and, per table, where each set's part starts (``bounds``, each an
    int64[sets + 1]): set ``t``'s own table is ``table[..., bound[t]:bound[t + 1]]`` (indices in
    it stay the set's own). ``set_routes`` cuts one set's out."""

    tables: Routes
    bounds: Routes


class RowState(NamedTuple):
    """The driver state of one provider's rows, kept between steps."""

    si: np.ndarray  # int64[NUM_INT_STATE, rows] SLOT, PREV_LANE, LC_LANE, LC_FROM
    st: np.ndarray  # float64[NUM_FLOAT_STATE, rows] S, LAT, LAT0, LC_PROG, COOL, FACTOR, WAIT
    pa: np.ndarray  # float64[NUM_PARAMS, rows] ACCEL ... KEEP_RIGHT
    mine: np.ndarray  # bool[rows] the provider drives the row


class Decisions(NamedTuple):
    """``step_vehicles``' scratch and results, per own vehicle (``turn``: per row)."""

    acc: np.ndarray  # float64[rows] acceleration decided
    guard: np.ndarray  # float64[rows] gap the move must stay within
    change: np.ndarray  # int64[rows] slot to change into, -1 none
    turn: np.ndarray  # int64[rows] by row: side of the lane change decided this step (+1 left)
    arrived: np.ndarray  # bool[rows] left the map at the end of its route


class RawEntries(NamedTuple):
    """Road users on lanes, unsorted (``build_occupancy``'s first pass)."""

    lane: np.ndarray  # int64[entries]
    s: np.ndarray  # float64[entries] arc length of the centre
    half: np.ndarray  # float64[entries] half length
    v: np.ndarray  # float64[entries] speed along the lane
    row: np.ndarray  # int64[entries]
    kind: np.ndarray  # int64[entries] PRIMARY, DUPLICATE or OVERHANG


class Occupancy(NamedTuple):
    """Road users on lanes: entries of lane ``l`` are ``lane_off[l]:lane_off[l + 1]``, sorted by
    (arc length, row)."""

    lane_off: np.ndarray  # int64[L + 1]
    s: np.ndarray  # float64[entries]
    half: np.ndarray  # float64[entries]
    v: np.ndarray  # float64[entries]
    row: np.ndarray  # int64[entries]
    kind: np.ndarray  # int64[entries]


class Others(NamedTuple):
    """Rows of other providers (agents, replay, ...) projected onto the map this step."""

    rows: np.ndarray  # int64[n]
    lane: np.ndarray  # int64[n], -1 off every lane
    s: np.ndarray  # float64[n]
    t: np.ndarray  # float64[n]
    dh: np.ndarray  # float64[n] heading minus the lane's heading


class JunctionView(NamedTuple):
    """What right of way (``_junction``) reads of one provider's step, gathered once per
    ``step_vehicles`` call. Only these arrays: a tuple passed to a function counts a reference to
    each of its arrays at every call, and these calls run for every vehicle near a junction (a
    tuple of the whole step made the traffic step about 20% slower at B = 256)."""

    si: np.ndarray
    st: np.ndarray
    pa: np.ndarray
    mine: np.ndarray
    lane_off: np.ndarray  # the step's Occupancy
    e_s: np.ndarray
    e_half: np.ndarray
    e_v: np.ndarray
    e_row: np.ndarray
    e_kind: np.ndarray
    lane_f: np.ndarray
    slot_int: np.ndarray
    conn_int: np.ndarray  # the set's Routes
    conn_len: np.ndarray
    clanes_off: np.ndarray
    clanes: np.ndarray
    offset_of_lane: np.ndarray
    foe_off: np.ndarray
    foe: np.ndarray
    foe_kind: np.ndarray
    zone: np.ndarray
    via_colour: np.ndarray  # the episode's signal colours


class ChangeView(NamedTuple):
    """What a lane-change check (``_try_change``) reads of one provider's step, gathered once per
    ``step_vehicles`` call (only these arrays, see ``JunctionView``)."""

    pa: np.ndarray
    st: np.ndarray
    mine: np.ndarray
    lane_off: np.ndarray
    e_s: np.ndarray
    e_half: np.ndarray
    e_v: np.ndarray
    e_row: np.ndarray
    lane_f: np.ndarray
    slot_int: np.ndarray
    pred_off: np.ndarray
    pred: np.ndarray


class Driver(NamedTuple):
    """The own vehicle deciding (built inside the kernel): its row, speed, half length, desired
    speed and driver parameters."""

    r: int
    v: float
    h: float
    v0: float
    accel: float
    decel: float
    tau: float
    s0: float
    emerg: float


class Mover(NamedTuple):
    """An own vehicle on a junction connection, as right of way sees it: ``p`` is its centre's
    position along the connection, ``bold`` its impatience, ``major`` and ``length`` its
    connection's."""

    me: Driver
    p: float
    bold: float
    major: int
    length: float


class Zone(NamedTuple):
    """A conflict zone with a foe connection: ``(zin, zout)`` on the own connection, ``(fin,
    fout)`` on the foe's; the foe's right of way, merge-only flag, length and signal colour."""

    kind: int
    zin: float
    zout: float
    fin: float
    fout: float
    major: int
    merge: bool
    length: float
    colour: int


class RoadUser(NamedTuple):
    """A road user on or approaching a foe connection: row ``w`` at ``p`` along it, speed, half
    length, whether it is own (with its driver's acceleration, deceleration, desired speed and
    waiting time; others get typical ones)."""

    w: int
    p: float
    v: float
    h: float
    own: bool
    accel: float
    decel: float
    v0: float
    wait: float


for _record in (LaneGraph, Routes, RouteSets, RowState):
    declare(_record)


@njit(nogil=True)
def freeze(fields):  # pragma: no cover - compiled
    """The frozen record of one of this module's records (see ``smarts.records``)."""
    return freeze_fields(fields)


@njit(nogil=True)
def set_routes(sets, t):  # pragma: no cover - compiled
    """Set ``t``'s ``Routes`` out of ``RouteSets`` ``sets`` (views)."""
    tb, b = sets.tables, sets.bounds
    return Routes(
        slot_int=tb.slot_int[:, b.slot_int[t] : b.slot_int[t + 1]],
        slot_cost=tb.slot_cost[b.slot_cost[t] : b.slot_cost[t + 1]],
        conn_int=tb.conn_int[:, b.conn_int[t] : b.conn_int[t + 1]],
        conn_len=tb.conn_len[b.conn_len[t] : b.conn_len[t + 1]],
        clanes_off=tb.clanes_off[b.clanes_off[t] : b.clanes_off[t + 1]],
        clanes=tb.clanes[b.clanes[t] : b.clanes[t + 1]],
        conn_of_lane=tb.conn_of_lane[b.conn_of_lane[t] : b.conn_of_lane[t + 1]],
        offset_of_lane=tb.offset_of_lane[b.offset_of_lane[t] : b.offset_of_lane[t + 1]],
        foe_off=tb.foe_off[b.foe_off[t] : b.foe_off[t + 1]],
        foe=tb.foe[b.foe[t] : b.foe[t + 1]],
        foe_kind=tb.foe_kind[b.foe_kind[t] : b.foe_kind[t + 1]],
        zone=tb.zone[:, b.zone[t] : b.zone[t + 1]],
    )


# ----------------------------------------------------------------------------- small helpers
# These run for every vehicle and lane entry and take just the arrays they read (never more than
# eleven parameters): a tuple argument counts a reference to each of its arrays at every call.
@njit(nogil=True)
def idm(v, v0, gap, v_lead, a, b, tau, s0):  # pragma: no cover - compiled
    """Intelligent Driver Model acceleration for a bumper-to-bumper ``gap`` to a leader."""
    free = 1.0 - (v / max(v0, 0.1)) ** IDM_DELTA
    if gap >= INF * 0.5:
        return a * free
    s_star = s0 + max(0.0, v * tau + v * (v - v_lead) / (2.0 * math.sqrt(a * b)))
    g = max(gap, 0.05)
    return a * (free - (s_star / g) ** 2)


@njit(nogil=True)
def travel_time(dist, v, a, v_max):  # pragma: no cover - compiled
    """Seconds to cover ``dist`` from speed ``v`` accelerating at ``a`` up to ``v_max``."""
    if dist <= 0.0:
        return 0.0
    if a <= 0.0:
        return dist / max(v, 0.1)
    top = max(v_max, v, 0.1)
    t1 = (top - v) / a
    d1 = 0.5 * (v + top) * t1
    if dist <= d1:
        return (-v + math.sqrt(v * v + 2.0 * a * dist)) / a
    return t1 + (dist - d1) / top


@njit(nogil=True)
def lane_pose(lane, s, point_off, point_s, points, seg_heading):  # pragma: no cover - compiled
    """Centre-line point and heading of ``lane`` at arc length ``s`` (extrapolated past the ends).

    The heading blends linearly between neighbouring segments' headings from one segment middle
    to the next, so it turns smoothly at the polyline's vertices instead of jumping.
    """
    a, b = point_off[lane], point_off[lane + 1]
    lo, hi = a, b - 2  # segment index range (segment k joins points k and k + 1)
    while lo < hi:
        mid = (lo + hi + 1) // 2
        if point_s[mid] <= s:
            lo = mid
        else:
            hi = mid - 1
    k = lo
    seg = point_s[k + 1] - point_s[k]
    u = (s - point_s[k]) / seg if seg > 1e-9 else 0.0
    x = points[k, 0] + u * (points[k + 1, 0] - points[k, 0])
    y = points[k, 1] + u * (points[k + 1, 1] - points[k, 1])
    h = seg_heading[k - lane]
    if u < 0.5 and k > a:
        other, w = seg_heading[k - 1 - lane], 0.5 - u
    elif u > 0.5 and k < b - 2:
        other, w = seg_heading[k + 1 - lane], u - 0.5
    else:
        return x, y, h
    w = min(w, 0.5)
    turn = math.atan2(math.sin(other - h), math.cos(other - h))
    return x, y, h + w * turn


@njit(nogil=True)
def _first_ahead(lane, s, row, lane_off, e_s, e_row):  # pragma: no cover - compiled
    """Index of the first entry on ``lane`` ordered after (s, row), skipping ``row``'s own
    entries, or -1. Entries are sorted by (arc length, row), so two road users at the same arc
    length still see one another as ahead and behind."""
    lo, hi = lane_off[lane], lane_off[lane + 1]
    while lo < hi:
        mid = (lo + hi) // 2
        if e_s[mid] < s or (e_s[mid] == s and e_row[mid] <= row):
            lo = mid + 1
        else:
            hi = mid
    k = lo
    end = lane_off[lane + 1]
    while k < end and e_row[k] == row:
        k += 1
    return k if k < end else -1


@njit(nogil=True)
def _last_behind(lane, s, row, lane_off, e_s, e_row):  # pragma: no cover - compiled
    """Index of the last entry on ``lane`` ordered before (s, row), skipping ``row``, or -1."""
    lo, hi = lane_off[lane], lane_off[lane + 1]
    while lo < hi:
        mid = (lo + hi) // 2
        if e_s[mid] < s or (e_s[mid] == s and e_row[mid] < row):
            lo = mid + 1
        else:
            hi = mid
    k = lo - 1
    start = lane_off[lane]
    while k >= start and e_row[k] == row:
        k -= 1
    return k if k >= start else -1


@njit(nogil=True)
def find_leader(slot, s, row, max_dist, slot_int, lane_f, lane_off, e_s, e_half, e_row):  # pragma: no cover
    """Entry ahead of arc length ``s`` on the slot's lane and the route's next lanes.

    Returns (entry index or -1, distance from ``s`` to that entry's rear).
    """
    lane = slot_int[S_LANE, slot]
    k = _first_ahead(lane, s, row, lane_off, e_s, e_row)
    if k >= 0:
        return k, e_s[k] - e_half[k] - s
    dist = lane_f[LEN, lane] - s
    nxt = slot_int[S_NEXT, slot]
    while nxt >= 0 and dist < max_dist:
        lane = slot_int[S_LANE, nxt]
        k = lane_off[lane]
        end = lane_off[lane + 1]
        while k < end and e_row[k] == row:
            k += 1
        if k < end:
            return k, dist + e_s[k] - e_half[k]
        dist += lane_f[LEN, lane]
        nxt = slot_int[S_NEXT, nxt]
    return -1, INF


@njit(nogil=True)
def find_follower(
    lane, s, row, max_back, lane_f, lane_off, e_s, e_half, e_row, pred_off, pred
):  # pragma: no cover - compiled
    """Entry behind arc length ``s`` on ``lane`` or, looking back up to ``max_back`` metres, on
    the lanes leading into it (the nearest one over all branches).

    Returns (entry index or -1, distance from that entry's front to ``s``).
    """
    k = _last_behind(lane, s, row, lane_off, e_s, e_row)
    if k >= 0:
        return k, s - e_s[k] - e_half[k]
    best, best_gap = -1, INF
    stack_lane = np.empty(FOLLOWER_STACK, dtype=np.int64)
    stack_dist = np.empty(FOLLOWER_STACK)
    top = 0
    for p in range(pred_off[lane], pred_off[lane + 1]):
        if top < FOLLOWER_STACK:
            stack_lane[top], stack_dist[top] = pred[p], s
            top += 1
    while top > 0:
        top -= 1
        pl, d = stack_lane[top], stack_dist[top]
        k = lane_off[pl + 1] - 1
        while k >= lane_off[pl] and e_row[k] == row:
            k -= 1
        if k >= lane_off[pl]:
            gap = d + lane_f[LEN, pl] - e_s[k] - e_half[k]
            if gap < best_gap:
                best, best_gap = k, gap
            continue
        d += lane_f[LEN, pl]
        if d >= max_back:
            continue
        for p in range(pred_off[pl], pred_off[pl + 1]):
            if top < FOLLOWER_STACK:
                stack_lane[top], stack_dist[top] = pred[p], d
                top += 1
    return best, best_gap


# ----------------------------------------------------------------------------- occupancy
@njit(nogil=True)
def _put(raw, n, lane, s, half, v, row, kind):  # pragma: no cover - compiled
    raw.lane[n], raw.s[n], raw.half[n] = lane, s, half
    raw.v[n], raw.row[n], raw.kind[n] = v, row, kind
    return n + 1


@njit(nogil=True)
def build_occupancy(own, others, data, state, lanes, routes, raw, occ):  # pragma: no cover - compiled
    """Fill ``occ`` (an ``Occupancy``; ``raw``, ``RawEntries`` of the same size, is scratch) with
    every road user on the lanes; returns the number of entries.

    Own vehicles (rows ``own``, their ``RowState`` ``state``) appear on their lane, on the lane
    they are leaving while a lane change still puts their body over it, and at the end of the
    previous lane while their rear overhangs it. Other rows (``others``, ``Others``) appear on
    their lane, on the neighbour lane their body reaches into, and on a single predecessor lane
    while their rear overhangs it, with their speed along the lane.
    """
    si, st = state.si, state.st
    slot_int = routes.slot_int
    lane_f, lane_lr, pred_off, pred = lanes.lane_f, lanes.lane_lr, lanes.pred_off, lanes.pred
    n = 0
    for i in range(own.shape[0]):
        r = own[i]
        lane = slot_int[S_LANE, si[SLOT, r]]
        s, half, v = st[S, r], 0.5 * data[_LENGTH, r], data[_V, r]
        n = _put(raw, n, lane, s, half, v, r, PRIMARY)
        src = si[LC_FROM, r]
        if (
            st[LC_PROG, r] < 1.0
            and si[LC_LANE, r] == lane
            and src >= 0
            and abs(st[LAT, r]) > 0.5 * (lane_f[WIDTH, lane] - data[_WIDTH, r]) - 0.2
        ):
            s_src = s * lane_f[LEN, src] / max(lane_f[LEN, lane], 1e-9)
            n = _put(raw, n, src, s_src, half, v, r, DUPLICATE)
        prev = si[PREV_LANE, r]
        if prev >= 0 and s < half:
            n = _put(raw, n, prev, lane_f[LEN, prev] + s, half, v, r, OVERHANG)
    for i in range(others.rows.shape[0]):
        r, lane = others.rows[i], others.lane[i]
        if lane < 0:
            continue
        half, w = 0.5 * data[_LENGTH, r], data[_WIDTH, r]
        reach = 0.5 * lane_f[WIDTH, lane]
        t = others.t[i]
        if abs(t) > reach + 0.5 * w:
            continue  # beside the lane, not on it
        v = max(data[_V, r] * math.cos(others.dh[i]), 0.0)
        s = others.s[i]
        n = _put(raw, n, lane, s, half, v, r, PRIMARY)
        if abs(t) + 0.5 * w > reach + 0.3:
            nb = lane_lr[0, lane] if t > 0 else lane_lr[1, lane]
            if nb >= 0:
                s_nb = s * lane_f[LEN, nb] / max(lane_f[LEN, lane], 1e-9)
                n = _put(raw, n, nb, s_nb, half, v, r, DUPLICATE)
        if s < half and pred_off[lane + 1] - pred_off[lane] == 1:
            p = pred[pred_off[lane]]
            n = _put(raw, n, p, lane_f[LEN, p] + s, half, v, r, OVERHANG)
    _sort_entries(n, raw, occ)
    return n


@njit(nogil=True)
def _sort_entries(n, raw, occ):  # pragma: no cover - compiled
    """Counting sort of the first ``n`` raw entries by lane into ``occ``, then insertion sort by
    arc length within each (short) lane list."""
    lane_off, raw_lane = occ.lane_off, raw.lane
    e_s, e_half, e_v, e_row, e_kind = occ.s, occ.half, occ.v, occ.row, occ.kind
    n_lanes = lane_off.shape[0] - 1
    for k in range(n_lanes + 1):
        lane_off[k] = 0
    for k in range(n):
        lane_off[raw_lane[k] + 1] += 1
    for k in range(n_lanes):
        lane_off[k + 1] += lane_off[k]
    cursor = lane_off[:-1].copy()
    for k in range(n):
        p = cursor[raw_lane[k]]
        cursor[raw_lane[k]] += 1
        e_s[p], e_half[p], e_v[p] = raw.s[k], raw.half[k], raw.v[k]
        e_row[p], e_kind[p] = raw.row[k], raw.kind[k]
    for lane in range(n_lanes):
        a, b = lane_off[lane], lane_off[lane + 1]
        for k in range(a + 1, b):
            j = k
            while j > a and (e_s[j - 1] > e_s[j] or (e_s[j - 1] == e_s[j] and e_row[j - 1] > e_row[j])):
                e_s[j - 1], e_s[j] = e_s[j], e_s[j - 1]
                e_half[j - 1], e_half[j] = e_half[j], e_half[j - 1]
                e_v[j - 1], e_v[j] = e_v[j], e_v[j - 1]
                e_row[j - 1], e_row[j] = e_row[j], e_row[j - 1]
                e_kind[j - 1], e_kind[j] = e_kind[j], e_kind[j - 1]
                j -= 1


# ----------------------------------------------------------------------------- driver model
@njit(nogil=True)
def desired_speed(r, lane, pa, st, lane_f):  # pragma: no cover - compiled
    return min(pa[MAX_SPEED, r], lane_f[SPEED_LIMIT, lane] * st[FACTOR, r])


@njit(nogil=True)
def impatience(r, st):  # pragma: no cover - compiled
    """1 + the share of IMPATIENCE_TIME that vehicle ``r`` has been waiting."""
    return 1.0 + min(st[WAIT, r] / IMPATIENCE_TIME, 1.0)


@njit(nogil=True)
def _other_accel(row, v, gap, v_lead, lane, mine, pa, st, lane_f):  # pragma: no cover - compiled
    """IDM acceleration of road user ``row`` (own: its parameters; others: typical ones)."""
    if mine[row]:
        v0 = desired_speed(row, lane, pa, st, lane_f)
        return idm(v, v0, gap, v_lead, pa[ACCEL, row], pa[DECEL, row], pa[TAU, row], pa[MIN_GAP, row])
    return idm(v, max(v, lane_f[SPEED_LIMIT, lane]), gap, v_lead, 2.6, 4.5, 1.0, 2.5)


@njit(nogil=True)
def _judge_foe(mover, zone, user, a_min, guard):  # pragma: no cover - compiled
    """Right of way between own vehicle ``r`` (``mover``: at ``p_v`` along its connection) and
    road user ``w`` (``user``: at ``p_w`` along the foe connection of conflict zone ``zone``).
    Returns the updated (acceleration bound, gap bound).
    """
    me = mover.me
    r, v, h, v0, accel, decel, tau, emerg = me.r, me.v, me.h, me.v0, me.accel, me.decel, me.tau, me.emerg
    p_v = mover.p
    kind, zin, zout, fin, fout = zone.kind, zone.zin, zone.zout, zone.fin, zone.fout
    w, p_w, v_w, h_w, w_own = user.w, user.p, user.v, user.h, user.own
    if w == r:
        return a_min, guard
    extra_v = max(h - NOMINAL_HALF, 0.0)
    extra_w = max(h_w - NOMINAL_HALF, 0.0)
    if kind == DIVERGE:  # same incoming lane: follow whoever is ahead on the shared start
        if p_w > p_v and p_w - extra_w < fout:
            gap = p_w - p_v - h - h_w
            a_min = min(a_min, idm(v, v0, gap, v_w, accel, decel, tau, WALL_MIN_GAP))
            if gap >= 0.0:
                guard = min(guard, gap)
        return a_min, guard
    if p_w - extra_w > fout:
        return a_min, guard  # it has left the zone
    v_in = p_v + h > 0.0
    w_in = p_w + h_w > 0.0
    if not w_in and _stops_at_own_light(zone.colour, p_w, h_w, v_w, user.decel):
        return a_min, guard
    if kind == MERGE:
        done, a_min, guard = _merge_rule(mover, zone, user, v_in, w_in, a_min, guard)
        if done:
            return a_min, guard
    t_vin = travel_time(zin - extra_v - p_v, v, accel, v0)
    t_vout = travel_time(zout + extra_v - p_v, v, accel, v0)
    wa = user.accel if w_own else 0.0
    t_win = travel_time(fin - extra_w - p_w, v_w, wa, user.v0)
    t_wout = travel_time(fout + extra_w - p_w, v_w, wa, user.v0)
    if not _foe_goes_first(mover, zone, user, v_in, w_in, wa, t_vin, t_win):
        return a_min, guard
    if t_vin > t_wout + CONFLICT_MARGIN or t_win > t_vout + CONFLICT_MARGIN:
        return a_min, guard  # their passages do not overlap in time
    gap = zin - extra_v - p_v  # how far the centre may still move before the zone
    if not v_in:
        gap = min(gap, -p_v - h)  # and not past the stop line
    if gap <= 0.0:
        return a_min, guard  # already in the zone: nothing left to yield
    if v * v <= 2.0 * emerg * max(gap - 0.1, 0.0):
        a_min = min(a_min, idm(v, v0, gap, 0.0, accel, decel, tau, WALL_MIN_GAP))
    return a_min, guard


# The rules of ``_judge_foe``, inlined into it by numba.
@njit(nogil=True, inline="always")
def _stops_at_own_light(colour_f, p_w, h_w, v_w, w_decel):  # pragma: no cover - compiled
    """Whether a road user ``p_w`` along its connection (not yet in it) will stop at its own red
    (or yellow) light."""
    if colour_f == 0:
        return False
    room = max(-p_w - h_w, 0.0)
    limit = 2.0 * w_decel if colour_f == RED else w_decel
    return colour_f <= YELLOW and v_w * v_w <= 2.0 * limit * room + 0.01


@njit(nogil=True, inline="always")
def _merge_rule(mover, zone, user, v_in, w_in, a_min, guard):  # pragma: no cover - compiled
    """Right of way where two connections merge: (decided, acceleration bound, gap bound); when not
    decided the crossing rule applies."""
    me = mover.me
    r, v, h, v0, accel, decel, tau = me.r, me.v, me.h, me.v0, me.accel, me.decel, me.tau
    p_v, w, p_w, v_w, h_w, w_decel = mover.p, user.w, user.p, user.v, user.h, user.decel
    delta = (mover.length - (zone.length - p_w)) - p_v
    ahead = delta > 0.0 or (delta == 0.0 and w < r)
    if w_in and ahead:
        gap = delta - h - h_w
        a_min = min(a_min, idm(v, v0, gap, v_w, accel, decel, tau, WALL_MIN_GAP))
        if gap >= 0.0:
            guard = min(guard, gap)
        return True, a_min, guard
    if w_in and v_in:
        return True, a_min, guard  # both in the junction and it is behind: it follows
    if ahead and not w_in and mover.major > zone.major and user.wait >= COURTESY_WAIT and zone.merge:
        # It has waited at its stop line to merge in ahead (and waits for nothing else, its
        # connection crossing no other): let it in if braking is easy.
        gap = delta - h - h_w
        a_courtesy = idm(v, v0, gap, v_w, accel, decel, tau, WALL_MIN_GAP)
        if gap > SAFE_GAP and a_courtesy >= -decel:
            return True, min(a_min, a_courtesy), min(guard, gap)
    if not ahead:  # it is behind on the merged path: go if it can follow comfortably
        gap_wv = -delta - h - h_w
        if (
            gap_wv > SAFE_GAP
            and idm(v_w, max(v_w, user.v0, 1.0), gap_wv, v, max(user.accel, 1.0), w_decel, 1.0, 2.5)
            >= -w_decel * mover.bold
        ):
            return True, a_min, guard
    return False, a_min, guard


@njit(nogil=True, inline="always")
def _foe_goes_first(mover, zone, user, v_in, w_in, wa, t_vin, t_win):  # pragma: no cover - compiled
    """Who goes first: whoever is already in the junction; else the connection with right of way;
    else whoever reaches its stop line first (a measure that does not depend on the pair, so the
    order is the same for everyone and waiting never goes round in a circle); inside, whoever
    reaches the zone first. True: the foe ``user``."""
    me, w = mover.me, user.w
    if v_in != w_in:
        return w_in
    if not v_in:
        if mover.major != zone.major:
            return zone.major > mover.major
        t_v = travel_time(-mover.p - me.h, me.v, me.accel, me.v0)
        t_w = travel_time(-user.p - user.h, user.v, wa, user.v0)
        return t_w < t_v or (t_w == t_v and w < me.r)
    return t_win < t_vin or (t_win == t_vin and w < me.r)


@njit(nogil=True)
def _junction(jv, me, c, p_v, a_min, guard):  # pragma: no cover - compiled
    """Apply right of way on connection ``c`` (own vehicle ``me``, a ``Driver``, at ``p_v`` along
    it) against every road user on or approaching a foe (``jv``: ``JunctionView``).

    Stays whole: its three loops as inlined helpers each took the ``JunctionView``'s arrays again
    per foe connection, and with the split ``step_vehicles`` the traffic step was 1.5-4x slower;
    the loops are numbered below instead."""
    si, st, pa, mine = jv.si, jv.st, jv.pa, jv.mine
    lane_off, e_s, e_half, e_v, e_row, e_kind = jv.lane_off, jv.e_s, jv.e_half, jv.e_v, jv.e_row, jv.e_kind
    lane_f, slot_int, conn_int, conn_len = jv.lane_f, jv.slot_int, jv.conn_int, jv.conn_len
    clanes_off, clanes, offset_of_lane = jv.clanes_off, jv.clanes, jv.offset_of_lane
    foe_off, foe, foe_kind, zone, via_colour = jv.foe_off, jv.foe, jv.foe_kind, jv.zone, jv.via_colour
    bold = impatience(me.r, st)
    major_c = conn_int[C_MAJOR, c]
    len_c = conn_len[c]
    mover = Mover(me=me, p=p_v, bold=bold, major=major_c, length=len_c)
    extra_v = max(me.h - NOMINAL_HALF, 0.0)
    for f in range(foe_off[c], foe_off[c + 1]):
        if p_v - extra_v > zone[1, f]:
            continue  # already past this zone
        fc = foe[f]
        fout = zone[3, f]
        len_f = conn_len[fc]
        first = conn_int[C_FIRST, fc]
        z = Zone(
            kind=foe_kind[f],
            zin=zone[0, f],
            zout=zone[1, f],
            fin=zone[2, f],
            fout=fout,
            major=conn_int[C_MAJOR, fc],
            merge=conn_int[C_MERGE_ONLY, fc] > 0,
            length=len_f,
            colour=via_colour[first],
        )
        # 1. on the foe's junction lanes
        for q in range(clanes_off[fc], clanes_off[fc + 1]):
            ln = clanes[q]
            for k in range(lane_off[ln], lane_off[ln + 1]):
                w = e_row[k]
                own_w = mine[w]
                user = RoadUser(
                    w=w,
                    p=offset_of_lane[ln] + e_s[k],
                    v=e_v[k],
                    h=e_half[k],
                    own=own_w,
                    accel=pa[ACCEL, w] if own_w else 0.0,
                    decel=pa[DECEL, w] if own_w else 4.5,
                    v0=desired_speed(w, ln, pa, st, lane_f) if own_w else e_v[k],
                    wait=st[WAIT, w] if own_w else 0.0,
                )
                a_min, guard = _judge_foe(mover, z, user, a_min, guard)
        # 2. just out of it, on its outgoing lane but maybe not yet out of the zone
        to = conn_int[C_TO, fc]
        beyond = max(fout - len_f, 0.0) + NOMINAL_HALF
        for k in range(lane_off[to], lane_off[to + 1]):
            if e_s[k] - e_half[k] > beyond:
                break
            user = RoadUser(
                w=e_row[k],
                p=len_f + e_s[k],
                v=e_v[k],
                h=e_half[k],
                own=False,
                accel=0.0,
                decel=4.5,
                v0=e_v[k],
                wait=0.0,
            )
            a_min, guard = _judge_foe(mover, z, user, a_min, guard)
        # 3. the first vehicle approaching on its incoming lane (those behind cannot enter
        #    before it has, and count once they are first)
        src = conn_int[C_FROM, fc]
        src_len = lane_f[LEN, src]
        for k in range(lane_off[src + 1] - 1, lane_off[src] - 1, -1):
            if e_kind[k] != PRIMARY:
                continue
            dist = src_len - e_s[k]
            if dist > APPROACH_RANGE:
                break
            w = e_row[k]
            own_w = mine[w]
            if own_w:
                nxt = slot_int[S_NEXT, si[SLOT, w]]
                if nxt < 0 or slot_int[S_LANE, nxt] != first:
                    break  # takes another way through the junction
            user = RoadUser(
                w=w,
                p=-dist,
                v=e_v[k],
                h=e_half[k],
                own=own_w,
                accel=pa[ACCEL, w] if own_w else 0.0,
                decel=pa[DECEL, w] if own_w else 4.5,
                v0=desired_speed(w, src, pa, st, lane_f) if own_w else e_v[k],
                wait=st[WAIT, w] if own_w else 0.0,
            )
            a_min, guard = _judge_foe(mover, z, user, a_min, guard)
            break
    return a_min, guard


@njit(nogil=True)
def _try_change(cv, me, slot, nslot, d, s, a_now, lead, mode, look):  # pragma: no cover - compiled
    """Check a lane change to ``nslot`` (side ``d``: +1 left, -1 right). mode 0: discretionary
    (MOBIL), 1: towards the route's preferred lane, 2: the lane ends. Returns (safe, incentive,
    own acceleration after, gap to the new leader).

    The politeness term weighs the new follower's loss and, for changes to the right only, the
    old follower's gain: drivers keep right to let others pass, but do not pull out to the left
    for a faster vehicle behind.

    ``cv``: the ``ChangeView``; ``me``: the ``Driver`` at arc length ``s`` on ``slot``;
    ``a_now``: its acceleration staying; ``lead``: its leader now (``Lead``); ``look``: how far
    ahead it looks."""
    pa, st, mine, lane_f, slot_int, pred_off, pred = cv.pa, cv.st, cv.mine, cv.lane_f, cv.slot_int, cv.pred_off, cv.pred
    lane_off, e_s, e_half, e_v, e_row = cv.lane_off, cv.e_s, cv.e_half, cv.e_v, cv.e_row
    r, v, h = me.r, me.v, me.h
    lead_gap, lead_v, has_lead = lead.gap, lead.v, lead.present
    lane = slot_int[S_LANE, slot]
    nlane = slot_int[S_LANE, nslot]
    s_n = min(max(s * lane_f[LEN, nlane] / max(lane_f[LEN, lane], 1e-9), 0.0), lane_f[LEN, nlane])
    accel, decel, tau, s0 = pa[ACCEL, r], pa[DECEL, r], pa[TAU, r], pa[MIN_GAP, r]
    v0_n = desired_speed(r, nlane, pa, st, lane_f)
    k, g = find_leader(nslot, s_n, r, look, slot_int, lane_f, lane_off, e_s, e_half, e_row)
    gap_nl = g - h
    v_nl = e_v[k] if k >= 0 else 0.0
    if gap_nl < SAFE_GAP:
        return False, 0.0, 0.0, gap_nl
    a_after = idm(v, v0_n, gap_nl, v_nl, accel, decel, tau, s0)
    if mode == 2:
        b_safe = decel * impatience(r, st)
    elif mode == 1:
        b_safe = B_SAFE_PREFERRED * impatience(r, st)
    else:
        b_safe = min(decel, B_SAFE_DISCRETIONARY)
    if a_after < -b_safe and mode < 2:
        return False, 0.0, a_after, gap_nl
    fk, fg = find_follower(nlane, s_n, r, FOLLOWER_LOOKBACK, lane_f, lane_off, e_s, e_half, e_row, pred_off, pred)
    gap_nf = fg - h
    a_nf_gain = 0.0
    if fk >= 0:
        if gap_nf < SAFE_GAP:
            return False, 0.0, a_after, gap_nl
        fr = e_row[fk]
        vf = e_v[fk]
        a_nf_after = _other_accel(fr, vf, gap_nf, v, nlane, mine, pa, st, lane_f)
        if a_nf_after < -b_safe:
            return False, 0.0, a_after, gap_nl
        if mode == 0:
            before_gap = gap_nf + 2.0 * h + gap_nl if k >= 0 else INF
            a_nf_gain = a_nf_after - _other_accel(fr, vf, before_gap, v_nl, nlane, mine, pa, st, lane_f)
    if mode > 0:
        return True, INF, a_after, gap_nl
    a_of_gain = 0.0
    ok, og = -1, INF
    if d < 0:
        ok, og = find_follower(lane, s, r, FOLLOWER_LOOKBACK, lane_f, lane_off, e_s, e_half, e_row, pred_off, pred)
    if ok >= 0:
        orow, vo = e_row[ok], e_v[ok]
        gap_of = og - h
        after_gap = gap_of + 2.0 * h + lead_gap if has_lead else INF
        a_of_gain = _other_accel(orow, vo, after_gap, lead_v, lane, mine, pa, st, lane_f) - _other_accel(
            orow, vo, gap_of, v, lane, mine, pa, st, lane_f
        )
    incentive = a_after - a_now + pa[POLITE, r] * (a_nf_gain + a_of_gain)
    return True, incentive, a_after, gap_nl


@njit(nogil=True)
def _neighbour_turns(slot, s, r, d, slot_int, lane_off, e_s, e_row, turn):  # pragma: no cover
    """Whether the road user just ahead or just behind on the lane has already decided this step
    to change lanes to the same side (decisions share one start-of-step state, so two of them
    could otherwise move into the same gap)."""
    lane = slot_int[S_LANE, slot]
    k = _first_ahead(lane, s, r, lane_off, e_s, e_row)
    if k >= 0 and turn[e_row[k]] == d:
        return True
    k = _last_behind(lane, s, r, lane_off, e_s, e_row)
    return k >= 0 and turn[e_row[k]] == d


class Lead(NamedTuple):
    """The road user a deciding vehicle follows now: bumper gap, its speed, whether there is one."""

    gap: float
    v: float
    present: bool


# ----------------------------------------------------------------------------- the step
@njit(nogil=True)
def step_vehicles(own, data, state, out, occ, lanes, routes, via_colour, dt, step):  # pragma: no cover - compiled
    """Advance every own vehicle (rows ``own`` of ``data``, their ``RowState`` ``state``) one step
    through the road users of ``occ`` (see the module docstring); ``out`` (``Decisions``) flags
    arrivals. ``via_colour``: the episode's signal colours; ``step``: its step count.

    Stays whole: the two passes split into inlined ``@njit`` helpers per vehicle (decide: lane
    left, courtesy, route ahead, lane change; move; pose) took the views' arrays through every
    helper and made the provider's step 1.5-4x slower (200 vehicles: 0.23 -> 0.66-1.01 ms of CPU
    time); the parts are marked by the comments below instead."""
    si, st, pa, mine = state.si, state.st, state.pa, state.mine
    lane_off, e_s, e_half, e_v, e_row, e_kind = occ.lane_off, occ.s, occ.half, occ.v, occ.row, occ.kind
    lane_f, lane_lr, slot_int, slot_cost = lanes.lane_f, lanes.lane_lr, routes.slot_int, routes.slot_cost
    point_off, point_s, points, seg_heading = lanes.point_off, lanes.point_s, lanes.points, lanes.seg_heading
    conn_of_lane, offset_of_lane = routes.conn_of_lane, routes.offset_of_lane
    arrived, acc, guard_out, change, turn = out.arrived, out.acc, out.guard, out.change, out.turn
    jv = JunctionView(
        si=si,
        st=st,
        pa=pa,
        mine=mine,
        lane_off=lane_off,
        e_s=e_s,
        e_half=e_half,
        e_v=e_v,
        e_row=e_row,
        e_kind=e_kind,
        lane_f=lane_f,
        slot_int=slot_int,
        conn_int=routes.conn_int,
        conn_len=routes.conn_len,
        clanes_off=routes.clanes_off,
        clanes=routes.clanes,
        offset_of_lane=offset_of_lane,
        foe_off=routes.foe_off,
        foe=routes.foe,
        foe_kind=routes.foe_kind,
        zone=routes.zone,
        via_colour=via_colour,
    )
    cv = ChangeView(
        pa=pa,
        st=st,
        mine=mine,
        lane_off=lane_off,
        e_s=e_s,
        e_half=e_half,
        e_v=e_v,
        e_row=e_row,
        lane_f=lane_f,
        slot_int=slot_int,
        pred_off=lanes.pred_off,
        pred=lanes.pred,
    )
    n = own.shape[0]
    for i in range(n):
        turn[own[i]] = 0
    # ---- pass 1: decisions from the start-of-step state
    for i in range(n):
        r = own[i]
        slot = si[SLOT, r]
        lane = slot_int[S_LANE, slot]
        s = st[S, r]
        v = data[_V, r]
        h = 0.5 * data[_LENGTH, r]
        accel, decel, emerg = pa[ACCEL, r], pa[DECEL, r], pa[EMERG, r]
        tau, s0 = pa[TAU, r], pa[MIN_GAP, r]
        v0 = desired_speed(r, lane, pa, st, lane_f)
        me = Driver(r=r, v=v, h=h, v0=v0, accel=accel, decel=decel, tau=tau, s0=s0, emerg=emerg)
        look = max(50.0, v * v / (2.0 * decel) + 3.0 * v + 20.0)
        # car following on the own route
        k, g = find_leader(slot, s, r, look, slot_int, lane_f, lane_off, e_s, e_half, e_row)
        lead_gap = g - h
        lead_v = e_v[k] if k >= 0 else 0.0
        a_cf = idm(v, v0, lead_gap if k >= 0 else INF, lead_v, accel, decel, tau, s0)
        a_min = a_cf
        guard = lead_gap if (k >= 0 and lead_gap >= 0.0) else INF
        # still partly on the lane being left: only avoid running into what is ahead there
        # (no time headway: the vehicle is on its way out of that lane)
        src = si[LC_FROM, r]
        if (
            st[LC_PROG, r] < 1.0
            and si[LC_LANE, r] == lane
            and src >= 0
            and abs(st[LAT, r]) > 0.5 * (lane_f[WIDTH, lane] - data[_WIDTH, r]) - 0.2
        ):
            s_src = s * lane_f[LEN, src] / max(lane_f[LEN, lane], 1e-9)
            k2 = _first_ahead(src, s_src, r, lane_off, e_s, e_row)
            if k2 >= 0:
                gap2 = e_s[k2] - e_half[k2] - s_src - h
                a_min = min(a_min, idm(v, v0, gap2, e_v[k2], accel, decel, 0.0, WALL_MIN_GAP))
                if gap2 >= 0.0:
                    guard = min(guard, gap2)
        # make room for a stopped neighbour that has waited to change into this lane
        if lane_f[INTERNAL, lane] == 0.0:
            for side in range(2):
                nb = lane_lr[side, lane]
                if nb < 0:
                    continue
                s_nb = s * lane_f[LEN, nb] / max(lane_f[LEN, lane], 1e-9)
                k3 = _first_ahead(nb, s_nb, r, lane_off, e_s, e_row)
                if k3 < 0 or e_kind[k3] != PRIMARY or not mine[e_row[k3]]:
                    continue
                w = e_row[k3]
                if st[WAIT, w] < COURTESY_WAIT or st[LC_PROG, w] < 1.0:
                    continue
                if slot_int[S_DIR, si[SLOT, w]] != (-1 if side == 0 else 1):
                    continue  # it does not need this lane
                gap3 = e_s[k3] - e_half[k3] - s_nb - h
                a_c = idm(v, v0, gap3, 0.0, accel, decel, tau, s0)
                if gap3 > SAFE_GAP and a_c >= -decel:
                    a_min = min(a_min, a_c)
                    guard = min(guard, gap3)
        # junction the vehicle is in
        c_here = conn_of_lane[lane]
        if c_here >= 0:
            a_min, guard = _junction(jv, me, c_here, offset_of_lane[lane] + s, a_min, guard)
        # the route ahead: lane ends, signals, junctions, lower speed limits
        dist = lane_f[LEN, lane] - s
        cur = slot
        cur_lane = lane
        while dist < look:
            nxt = slot_int[S_NEXT, cur]
            if nxt == NEXT_ARRIVE:
                break
            if nxt == NEXT_NONE:
                gap = dist - h
                a_min = min(a_min, idm(v, v0, gap, 0.0, accel, decel, tau, WALL_MIN_GAP))
                break
            nlane = slot_int[S_LANE, nxt]
            if lane_f[INTERNAL, nlane] > 0.0 and lane_f[INTERNAL, cur_lane] == 0.0:
                gap = dist - h
                colour = via_colour[nlane]
                stop = False
                if colour == RED:
                    stop = v * v <= 2.0 * emerg * max(gap, 0.0)
                elif colour == YELLOW:
                    stop = v * v <= 2.0 * decel * max(gap, 0.0)
                if stop:
                    a_min = min(a_min, idm(v, v0, gap, 0.0, accel, decel, tau, WALL_MIN_GAP))
                    break
                c = conn_of_lane[nlane]
                if c >= 0:
                    a_min, guard = _junction(jv, me, c, -dist, a_min, guard)
            v_next = desired_speed(r, nlane, pa, st, lane_f)
            if v > v_next:
                a_min = min(a_min, (v_next * v_next - v * v) / (2.0 * max(dist, 1.0)))
            dist += lane_f[LEN, nlane]
            cur = nxt
            cur_lane = nlane
        # lane changes
        change[i] = -1
        if lane_f[INTERNAL, lane] == 0.0 and st[LC_PROG, r] >= 1.0:
            want = slot_int[S_DIR, slot]
            ends = slot_int[S_NEXT, slot] == NEXT_NONE
            best_inc = -INF
            best_slot = -1
            best_a = 0.0
            best_gap = INF
            for side in range(2):
                d = 1 if side == 0 else -1
                if (step % 2 == 0) != (d > 0):
                    continue  # left changes on even steps, right on odd: no two into one gap
                nslot = slot_int[S_LEFT, slot] if d > 0 else slot_int[S_RIGHT, slot]
                if nslot < 0:
                    continue
                if lane_f[LEN, lane] - s < v * LC_DURATION + h:
                    continue  # the sideways move must end before the lane does
                if want != 0 and d == want:
                    mode = 2 if ends else 1
                elif want != 0 or slot_cost[nslot] > slot_cost[slot]:
                    continue
                else:
                    mode = 0
                    if st[COOL, r] > 0.0 or v < 1.0:
                        continue
                    if lane_f[LEN, lane] - s < MIN_CHANGE_ROOM + v:
                        continue
                if _neighbour_turns(slot, s, r, d, slot_int, lane_off, e_s, e_row, turn):
                    continue  # the vehicle just ahead or behind moves over this step
                lead = Lead(gap=lead_gap, v=lead_v, present=k >= 0)
                ok, inc, a_after, gap_after = _try_change(cv, me, slot, nslot, d, s, a_cf, lead, mode, look)
                if not ok:
                    continue
                if mode == 0:
                    bias = KEEP_RIGHT_BIAS * pa[KEEP_RIGHT, r]
                    need = pa[THRESH, r] + (bias if d > 0 else -bias)
                    if inc <= need:
                        continue
                    inc -= need
                if inc > best_inc:
                    best_inc, best_slot, best_a, best_gap = inc, nslot, a_after, gap_after
            if best_slot >= 0:
                change[i] = best_slot
                turn[r] = 1 if best_slot == slot_int[S_LEFT, slot] else -1
                a_min = min(a_min, best_a)
                if best_gap >= 0.0:
                    guard = min(guard, best_gap)
        acc[i] = min(max(a_min, -emerg), accel)
        guard_out[i] = guard
    # ---- pass 2: move
    for i in range(n):
        r = own[i]
        arrived[i] = False
        slot = si[SLOT, r]
        lane = slot_int[S_LANE, slot]
        s = st[S, r]
        if change[i] >= 0:
            nslot = change[i]
            nlane = slot_int[S_LANE, nslot]
            d = 1.0 if nslot == slot_int[S_LEFT, slot] else -1.0
            offset = 0.5 * (lane_f[WIDTH, lane] + lane_f[WIDTH, nlane])
            st[LAT0, r] = st[LAT, r] - d * offset
            st[LAT, r] = st[LAT0, r]
            st[LC_PROG, r] = 0.0
            st[COOL, r] = LC_DURATION + LC_COOLDOWN
            s = min(max(s * lane_f[LEN, nlane] / max(lane_f[LEN, lane], 1e-9), 0.0), lane_f[LEN, nlane])
            si[LC_FROM, r] = lane
            si[LC_LANE, r] = nlane
            slot, lane = nslot, nlane
        v = data[_V, r]
        a = acc[i]
        v_new = v + a * dt
        if v_new < 0.0:
            ds = v * v / (-2.0 * a) if a < 0.0 else 0.0
            v_new = 0.0
        else:
            ds = 0.5 * (v + v_new) * dt
        g = guard_out[i] - GUARD_MARGIN
        if g < INF * 0.5 and ds > g:
            ds = max(g, 0.0)
            v_new = max(0.0, min(v_new, 2.0 * ds / dt - v))  # constant deceleration over ds
        s += ds
        while s > lane_f[LEN, lane]:
            nxt = slot_int[S_NEXT, slot]
            if nxt >= 0:
                s -= lane_f[LEN, lane]
                si[PREV_LANE, r] = lane
                slot = nxt
                lane = slot_int[S_LANE, slot]
            elif nxt == NEXT_ARRIVE:
                arrived[i] = True
                break
            else:
                s = lane_f[LEN, lane]
                v_new = 0.0
                break
        si[SLOT, r] = slot
        st[S, r] = s
        st[WAIT, r] = st[WAIT, r] + dt if v_new < 0.5 else 0.0
        # lateral offset of a lane change (or of an adopted vehicle) decaying to the centre
        lat_rate = 0.0
        if st[LC_PROG, r] < 1.0:
            u = min(st[LC_PROG, r] + dt / LC_DURATION, 1.0)
            st[LC_PROG, r] = u
            st[LAT, r] = st[LAT0, r] * (1.0 - u * u * (3.0 - 2.0 * u))
            lat_rate = -st[LAT0, r] * 6.0 * u * (1.0 - u) / LC_DURATION
        else:
            st[LAT, r] = 0.0
        st[COOL, r] -= dt
        x, y, hd = lane_pose(lane, s, point_off, point_s, points, seg_heading)
        lat = st[LAT, r]
        x -= lat * math.sin(hd)
        y += lat * math.cos(hd)
        heading = hd + math.atan2(lat_rate, max(v_new, 3.0))
        heading = math.atan2(math.sin(heading), math.cos(heading))
        dh = heading - data[_H, r]
        dh = math.atan2(math.sin(dh), math.cos(dh))
        a_real = (v_new - v) / dt
        data[_J, r] = (a_real - data[_A, r]) / dt
        data[_A, r] = a_real
        data[_X, r], data[_Y, r], data[_H, r], data[_V, r] = x, y, heading, v_new
        data[_YAW, r] = dh / dt
        data[_LATA, r] = v_new * dh / dt


@njit(nogil=True)
def place_vehicle(frozen_lanes, frozen_routes, frozen_state, data, r):  # pragma: no cover - compiled
    """Write the pose of own vehicle ``r`` into ``data`` from its slot, arc length and lateral
    offset (frozen ``LaneGraph``, ``Routes`` and ``RowState``)."""
    lanes, si, st = frozen_lanes, frozen_state.si, frozen_state.st
    lane = frozen_routes.slot_int[S_LANE, si[SLOT, r]]
    x, y, hd = lane_pose(lane, st[S, r], lanes.point_off, lanes.point_s, lanes.points, lanes.seg_heading)
    lat = st[LAT, r]
    data[_X, r] = x - lat * math.sin(hd)
    data[_Y, r] = y + lat * math.cos(hd)
    data[_H, r] = math.atan2(math.sin(hd), math.cos(hd))


@njit(nogil=True)
def clearance(
    frozen_lanes,
    frozen_routes,
    frozen_state,
    data,
    own,
    f_rows,
    f_lane,
    f_s,
    lanes,
    spots,
    next_lanes,
    half,
):  # pragma: no cover - compiled
    """Room around entry spots (``lanes``, arc lengths ``spots``, the lane after each on the
    route, -1 none) for a new vehicle of half length ``half``: float64[4, n] of gap ahead, speed
    of the road user ahead, gap behind, speed of the one behind (INF: none). Scans every road
    user on each spot's lane and on the lane after it: own vehicles ``own`` (frozen ``RowState``)
    and other rows ``f_rows`` on ``f_lane`` at ``f_s``."""
    lane_f, slot_int, si, st = frozen_lanes.lane_f, frozen_routes.slot_int, frozen_state.si, frozen_state.st
    n = lanes.shape[0]
    out = np.empty((4, n))
    for c in range(n):
        lane, s, next_lane = lanes[c], spots[c], next_lanes[c]
        ahead, v_ahead, behind, v_behind = INF, 0.0, INF, 0.0
        for i in range(own.shape[0] + f_rows.shape[0]):
            if i < own.shape[0]:
                r = own[i]
                ln = slot_int[S_LANE, si[SLOT, r]]
                es = st[S, r]
                if ln != lane and si[LC_FROM, r] == lane and st[LC_PROG, r] < 1.0:
                    es = es * lane_f[LEN, lane] / max(lane_f[LEN, ln], 1e-9)
                    ln = lane
            else:
                j = i - own.shape[0]
                r, ln, es = f_rows[j], f_lane[j], f_s[j]
            if ln == next_lane and next_lane >= 0:
                es += lane_f[LEN, lane]
                ln = lane
            if ln != lane:
                continue
            eh = 0.5 * data[_LENGTH, r]
            if es >= s:
                gap = es - eh - s - half
                if gap < ahead:
                    ahead, v_ahead = gap, data[_V, r]
            else:
                gap = s - half - es - eh
                if gap < behind:
                    behind, v_behind = gap, data[_V, r]
        out[0, c], out[1, c], out[2, c], out[3, c] = ahead, v_ahead, behind, v_behind
    return out
