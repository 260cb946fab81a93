"""Which vehicle an agent follows and where that lead is: one definition for every consumer.

The lead observation block (``smarts.sensors``), the platoon reward (``smarts.env``) and the
benchmark's SFD columns (``smarts.benchmark.recorder``) all read :func:`lead_state`, so "the lead
is in my lane" and "the gap to the lead" mean the same thing to a policy, its reward and its score.

Lane continuity: the lead is *in the follower's lane* when it is ahead on the follower's own lane,
or on a lane reached from it by successor lanes (through junctions, any branch), with at most
``sight`` metres of lane between their centres. The gap is then the distance along those lanes
from the follower's front bumper to the lead's rear bumper, so a lead straight ahead stays in lane
across road-segment boundaries. Inside junctions, where internal lanes overlap and the projection
may put two vehicles on neighbouring connections, a lead less than half a lane width to the side
of the follower's heading line also counts as in lane.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np

from smarts.compiled import njit
from smarts.core.sim_records import lanes_record
from smarts.core.vehicle_table import COLUMN

_X, _Y, _H = COLUMN["x"], COLUMN["y"], COLUMN["heading"]
_SPEED, _ACCEL, _LENGTH, _S = COLUMN["speed"], COLUMN["accel"], COLUMN["length"], COLUMN["s"]

LEAD_SIGHT = 50.0
"""Metres between the centres (along the lane, or straight) within which the lead is visible."""


# The lead kernel writes two blocks, one row per field (``LeadState``'s arrays are these rows):
# a call from Python types each argument, and a tuple of eleven arrays costs about 3 us more to
# type than two arrays (measured with numba 0.68), several times the kernel's work at one agent.
_PRESENT, _VISIBLE, _IN_LANE = range(3)  # rows of the flags block (bool)
_GAP, _DX, _DY, _REL_HEADING, _REL_VX, _REL_VY, _LEAD_SPEED, _LEAD_ACCEL = range(8)  # rows of the values block


class LeadState(NamedTuple):
    """Per agent (in the order asked for): the lead's state relative to the agent."""

    present: np.ndarray  # bool[n] the agent follows a vehicle that is in the simulation now
    visible: np.ndarray  # bool[n] present and within sight (centre distance <= sight)
    in_lane: np.ndarray  # bool[n] visible, ahead and in the follower's lane (lane continuity)
    gap: np.ndarray  # float64[n] bumper-to-bumper metres: along the lanes when in lane, else
    # along the follower's heading; NaN when not visible
    dx: np.ndarray  # float64[n] lead centre in the follower's frame (m, x forward, y left)
    dy: np.ndarray
    rel_heading: np.ndarray  # float64[n] lead heading minus follower heading (rad, wrapped)
    rel_vx: np.ndarray  # float64[n] lead velocity minus follower velocity, follower frame (m/s)
    rel_vy: np.ndarray
    lead_speed: np.ndarray  # float64[n] m/s
    lead_accel: np.ndarray  # float64[n] m/s^2

    @classmethod
    def empty(cls, n: int) -> "LeadState":
        return cls.of_blocks(*_lead_blocks(n))

    @classmethod
    def of_blocks(cls, flags: np.ndarray, values: np.ndarray) -> "LeadState":
        """The state whose arrays are the rows of the lead kernel's blocks."""
        return cls(
            present=flags[_PRESENT], visible=flags[_VISIBLE], in_lane=flags[_IN_LANE], gap=values[_GAP],
            dx=values[_DX], dy=values[_DY], rel_heading=values[_REL_HEADING], rel_vx=values[_REL_VX],
            rel_vy=values[_REL_VY], lead_speed=values[_LEAD_SPEED], lead_accel=values[_LEAD_ACCEL],
        )  # fmt: skip


def _lead_blocks(n: int) -> tuple[np.ndarray, np.ndarray]:
    """The lead kernel's empty output: nothing present, gap NaN."""
    flags = np.zeros((3, n), dtype=bool)
    values = np.zeros((8, n))
    values[_GAP] = np.nan
    return flags, values


def _lead_cache(sim) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per agent: cached lead row, that row's serial, whether the agent follows a lead at all."""
    table = sim.table
    cache = table.__dict__.get("_lead_row_cache")  # this object's own, also under wrappers
    if cache is None or len(cache[0]) != len(sim.lead_ids):
        n = len(sim.lead_ids)
        cache = (np.full(n, -1, dtype=np.int64), np.zeros(n, dtype=np.int64),
                 np.array([lead is not None for lead in sim.lead_ids], dtype=bool))  # fmt: skip
        table.__dict__["_lead_row_cache"] = cache
    return cache


def lead_rows(sim, agents: np.ndarray) -> np.ndarray:
    """Table row of each agent's lead vehicle, -1 where it follows none or the lead is gone.

    Rows are cached per agent (on the table object, which views of a simulation for one step
    share) with the row's serial: a cached row that is alive with the same serial still holds the
    lead, so only agents whose lead came, went or was never found look it up by id."""
    agents = np.asarray(agents, dtype=np.int64)
    table = sim.table
    rows, serials, has_lead = _lead_cache(sim)
    cached = rows[agents]
    hit = (cached >= 0) & table.alive[cached] & (table.serial[cached] == serials[agents])
    out = np.where(hit, cached, -1)
    ids, row_of = sim.lead_ids, table.row_of
    for k in np.flatnonzero(~hit & has_lead[agents]).tolist():
        a = int(agents[k])
        row = row_of.get(ids[a], -1)
        out[k] = row
        rows[a] = row
        if row >= 0:
            serials[a] = table.serial[row]
    return out


def lead_state(sim, agents: np.ndarray, sight: float = LEAD_SIGHT) -> LeadState:
    """The lead of each agent in ``agents`` (agent indices), from the simulation's current state."""
    agents = np.asarray(agents, dtype=np.int64)
    n = len(agents)
    if n == 0 or not _lead_cache(sim)[2][agents].any():
        return LeadState.empty(n)
    leads = lead_rows(sim, agents)
    rows = sim.agent_row[agents]
    flags, values = _lead_blocks(n)
    _lead_kernel(lanes_record(sim.road_map), sim.table.data, sim.table.lane, rows, leads, float(sight), flags, values)
    return LeadState.of_blocks(flags, values)


class Successors(NamedTuple):
    """The lane graph forward: a ``Lanes`` record's successors (CSR) and lane lengths."""

    offsets: np.ndarray  # int64[L + 1]
    succ: np.ndarray  # int32[E]
    length: np.ndarray  # float64[L]


@njit(nogil=True)
def lane_distance_ahead(graph, from_lane, from_s, to_lane, to_s, limit):  # pragma: no cover - compiled
    """Metres along the lane graph (``graph``, ``Successors``) from (from_lane, from_s) forward
    to (to_lane, to_s); inf when ``to_lane`` is not reached within ``limit`` metres (or lies
    behind on the same lane)."""
    succ_offsets, succ, lane_length = graph.offsets, graph.succ, graph.length
    if from_lane == to_lane:
        return to_s - from_s if to_s >= from_s else np.inf
    stack_lane = np.empty(128, dtype=np.int64)
    stack_d = np.empty(128)
    top = 0
    rest = max(lane_length[from_lane] - from_s, 0.0)
    for k in range(succ_offsets[from_lane], succ_offsets[from_lane + 1]):
        if top < 128:
            stack_lane[top], stack_d[top] = succ[k], rest
            top += 1
    best = np.inf
    while top > 0:
        top -= 1
        lane, d = stack_lane[top], stack_d[top]
        if d > limit or d >= best:
            continue
        if lane == to_lane:
            best = min(best, d + max(to_s, 0.0))
            continue
        nd = d + lane_length[lane]
        for k in range(succ_offsets[lane], succ_offsets[lane + 1]):
            if top < 128:
                stack_lane[top], stack_d[top] = succ[k], nd
                top += 1
    return best


@njit(nogil=True)
def _lead_kernel(frozen_lanes, data, lane, rows, leads, sight, flags, values):  # pragma: no cover - compiled
    """``lead_state`` of the agents on ``rows`` (their leads on ``leads``) into the rows of
    ``flags`` and ``values`` (``_PRESENT``..., ``_GAP``...); ``frozen_lanes`` is the map's frozen
    ``Lanes``."""
    lanes = frozen_lanes
    graph = Successors(offsets=lanes.succ_offsets, succ=lanes.succ, length=lanes.length)
    lane_internal, lane_width = lanes.internal, lanes.width
    present, visible, in_lane = flags[_PRESENT], flags[_VISIBLE], flags[_IN_LANE]
    gap, dx_out, dy_out, rel_h = values[_GAP], values[_DX], values[_DY], values[_REL_HEADING]
    rel_vx, rel_vy, lead_speed, lead_accel = values[_REL_VX], values[_REL_VY], values[_LEAD_SPEED], values[_LEAD_ACCEL]
    for i in range(rows.shape[0]):
        r, j = rows[i], leads[i]
        if j < 0 or r < 0:
            continue
        present[i] = True
        x, y, h, v = data[_X, r], data[_Y, r], data[_H, r], data[_SPEED, r]
        c, s = math.cos(h), math.sin(h)
        ddx, ddy = data[_X, j] - x, data[_Y, j] - y
        if ddx * ddx + ddy * ddy > sight * sight:
            continue
        visible[i] = True
        fx, fy = c * ddx + s * ddy, c * ddy - s * ddx
        dh = data[_H, j] - h
        dh = dh - 2.0 * math.pi * math.floor((dh + math.pi) / (2.0 * math.pi))
        vj = data[_SPEED, j]
        dx_out[i], dy_out[i], rel_h[i] = fx, fy, dh
        rel_vx[i] = vj * math.cos(dh) - v
        rel_vy[i] = vj * math.sin(dh)
        lead_speed[i], lead_accel[i] = vj, data[_ACCEL, j]
        half_lengths = 0.5 * (data[_LENGTH, r] + data[_LENGTH, j])
        gap[i] = fx - half_lengths
        lf, lj = lane[r], lane[j]
        if lf < 0 or lj < 0:
            continue
        along = lane_distance_ahead(graph, lf, data[_S, r], lj, data[_S, j], sight)
        if along <= sight and along > 0.0:
            in_lane[i] = True
            gap[i] = along - half_lengths
        elif (lane_internal[lf] or lane_internal[lj]) and fx > 0.0 and abs(fy) < 0.5 * lane_width[lf]:
            in_lane[i] = True


_A_GAP, _A_REL_SPEED, _A_SPEED, _A_ACCEL = range(4)  # rows of the ahead kernel's values block (see _PRESENT)


class AheadState(NamedTuple):
    """Per agent: the nearest road user ahead on the agent's lane (lane continuity, any vehicle)."""

    present: np.ndarray  # bool[n] one is within ``sight`` metres of lane ahead
    gap: np.ndarray  # float64[n] bumper-to-bumper metres along the lanes (sight when none)
    rel_speed: np.ndarray  # float64[n] its speed along its heading minus the agent's (m/s; 0 when none)
    speed: np.ndarray  # float64[n] m/s
    accel: np.ndarray  # float64[n] m/s^2


def ahead_state(sim, agents: np.ndarray, sight: float = LEAD_SIGHT) -> AheadState:
    """The nearest road user ahead of each agent on its lane or a lane it leads to, within ``sight``
    metres along the lanes (the vehicle a driver keeps a gap to, whoever it is)."""
    agents = np.asarray(agents, dtype=np.int64)
    n = len(agents)
    present = np.zeros(n, bool)
    values = np.zeros((4, n))
    values[_A_GAP] = float(sight)
    if n:
        scope = sim.scope(agents)  # each agent among its own episode's road users
        _ahead_kernel(
            lanes_record(sim.road_map), sim.table.data, sim.table.lane, sim.agent_row[agents], scope.alive, scope.lo,
            scope.hi, float(sight), present, values,
        )  # fmt: skip
    return AheadState(present=present, gap=values[_A_GAP], rel_speed=values[_A_REL_SPEED], speed=values[_A_SPEED],
                      accel=values[_A_ACCEL])  # fmt: skip


@njit(nogil=True)
def _ahead_kernel(
    frozen_lanes, data, lane, rows, alive, alive_lo, alive_hi, sight, present, values
):  # pragma: no cover - compiled
    """``ahead_state`` of the agents on ``rows`` among the live rows of their episodes
    (``alive[alive_lo[i]:alive_hi[i]]``) into ``present`` and the rows of ``values``
    (``_A_GAP``...)."""
    graph = Successors(offsets=frozen_lanes.succ_offsets, succ=frozen_lanes.succ, length=frozen_lanes.length)
    gap, rel_speed, speed, accel = values[_A_GAP], values[_A_REL_SPEED], values[_A_SPEED], values[_A_ACCEL]
    for i in range(rows.shape[0]):
        r = rows[i]
        if r < 0 or lane[r] < 0:
            continue
        x, y, h, v = data[_X, r], data[_Y, r], data[_H, r], data[_SPEED, r]
        best = sight
        for j in alive[alive_lo[i] : alive_hi[i]]:
            if j == r or lane[j] < 0:
                continue
            dx, dy = data[_X, j] - x, data[_Y, j] - y
            if dx * dx + dy * dy > (sight + 15.0) ** 2:
                continue
            along = lane_distance_ahead(graph, lane[r], data[_S, r], lane[j], data[_S, j], sight)
            if along <= 0.0 or along > sight:
                continue
            g = along - 0.5 * (data[_LENGTH, r] + data[_LENGTH, j])
            if g < best:
                best = g
                present[i] = True
                gap[i] = g
                rel = data[_H, j] - h
                speed[i] = data[_SPEED, j]
                rel_speed[i] = data[_SPEED, j] * math.cos(rel) - v
                accel[i] = data[_ACCEL, j]
