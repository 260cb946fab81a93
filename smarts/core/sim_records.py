"""A simulation's arrays as one kernel record (``smarts.records``): what its per-step kernels
(events, route progress, observations, the lead and the vehicle ahead, lane-relative control)
read, named.

Everything here is built once per simulation (``sim_tables``) and holds the simulation's own
arrays, not copies: a kernel that writes ``tables.agent_events`` writes ``Simulation.agent_events``.
What changes from step to step (the live rows, the clock, the agents asked about) is passed to each
kernel beside it. The simulation allocates these arrays once, in its constructor; should it ever
replace one, ``tests/core/test_sim_records.py`` fails (a record would go on holding the old one).
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from smarts.compiled import njit
from smarts.records import declare, freeze_fields


class Lanes(NamedTuple):
    """A road map's lanes (``RoadMap``'s arrays: for a stack of maps, the combined map's)."""

    length: np.ndarray  # float64[L] arc length of the centre line
    width: np.ndarray  # float64[L]
    speed_limit: np.ndarray  # float64[L] m/s
    road: np.ndarray  # int32[L] road of each lane
    index: np.ndarray  # int16[L] position on its road, 0 = rightmost
    internal: np.ndarray  # bool[L] inside a junction
    left: np.ndarray  # int32[L] neighbour to the left, -1 none
    right: np.ndarray  # int32[L] neighbour to the right, -1 none
    succ_offsets: np.ndarray  # int64[L + 1] CSR of each lane's successors
    succ: np.ndarray  # int32[E]
    point_offsets: np.ndarray  # int64[L + 1] CSR of each lane's points, resampled every metre
    points: np.ndarray  # float64[Q, 2]
    point_s: np.ndarray  # float64[Q] arc length of each point within its lane
    point_heading: np.ndarray  # float64[Q]


class SimTables(NamedTuple):
    """Everything of a simulation that its per-step kernels read and that stays in place, under
    the simulation's own names where it has one.

    One level, no nested tuples: a kernel reads the few fields it uses (``tables.goal_s``), each
    one load; a nested tuple would be read whole (every array in it counted as a new reference)
    to get at one of its arrays."""

    # the vehicle table (``VehicleTable``) and its rows' not-moving anchors
    data: np.ndarray  # float64[columns, rows]
    alive: np.ndarray  # bool[rows]
    row_map: np.ndarray  # int64[rows] map of each row's episode in the stack
    lane: np.ndarray  # int32[rows] projected lane, -1 off every lane
    role: np.ndarray  # int8[rows]
    vtype: np.ndarray  # int8[rows]
    anchor: np.ndarray  # float64[rows, 2] where the row last moved more than the distance
    anchor_time: np.ndarray  # float64[rows] when
    # the lanes (``RoadMap``; for a stack of maps, the combined map's)
    lane_length: np.ndarray  # float64[L]
    lane_width: np.ndarray  # float64[L]
    lane_speed_limit: np.ndarray  # float64[L] m/s
    lane_road: np.ndarray  # int32[L]
    lane_index: np.ndarray  # int16[L] position on its road, 0 = rightmost
    lane_internal: np.ndarray  # bool[L] inside a junction
    lane_succ_offsets: np.ndarray  # int64[L + 1] CSR of each lane's successors (none: the map ends)
    # every map's projection grid over one segment table (``smarts.maps.projection.Grids``)
    grid_table: np.ndarray  # float64[14, S]
    grid_offsets: np.ndarray  # intp[cells + 1]
    grid_segs: np.ndarray  # intp[...]
    grid_cell_base: np.ndarray  # int64[M]
    grid_ny: np.ndarray  # int64[M]
    grid_origin: np.ndarray  # float64[M, 2]
    grid_inv_cell: np.ndarray  # float64[M]
    grid_cell_max: np.ndarray  # float64[M, 2]
    # every map's drivable raster, concatenated as ``MapStack`` stacks them: map m's cells are
    # raster_flat[raster_base[m]:raster_base[m + 1]], raster_width[m] a row
    raster_flat: np.ndarray  # bool[cells of every map]
    raster_base: np.ndarray  # int64[M + 1]
    raster_width: np.ndarray  # int64[M]
    raster_origin: np.ndarray  # float64[M, 2]
    raster_inv_res: np.ndarray  # float64[M]
    raster_cell_max: np.ndarray  # float64[M, 2] largest cell index (x, y)
    # every agent's mission (``MissionArrays``)
    flat_paths: np.ndarray  # float64[A * stride, 3, 3] point i of agent a at row a * stride + i
    flat_valid: np.ndarray  # bool[A * stride, 3]
    stride: int  # route points per agent (padded)
    path_len: np.ndarray  # int64[A] valid route points
    path_s: np.ndarray  # float64[A, stride] arc length of each route point
    route_length: np.ndarray  # float64[A]
    on_route_road: np.ndarray  # bool[A, R]
    goal_kind: np.ndarray  # int8[A] 0 none, 1 position, 2 road (see ``agent_events``)
    goal_xy: np.ndarray  # float64[A, 2]
    goal_radius: np.ndarray  # float64[A]
    goal_road: np.ndarray  # int32[A]
    goal_lane: np.ndarray  # int32[A], -1: any lane of the road
    goal_s: np.ndarray  # float64[A]
    goal_gate: np.ndarray  # float64[A, 6] goal line (see ``crosses_gate``)
    signal_via: np.ndarray  # int32[A * stride] next signal-controlled lane from each route point
    signal_s: np.ndarray  # float64[A * stride] route arc length of its stop line
    # what the simulation keeps per agent between steps
    agent_episode: np.ndarray  # int64[A]
    agent_active: np.ndarray  # bool[A] still in its episode
    agent_row: np.ndarray  # int64[A] its vehicle's row (-1: none)
    agent_events: np.ndarray  # bool[A, NUM_EVENTS] this step's events
    agent_done: np.ndarray  # bool[A]
    prev_xy: np.ndarray  # float64[A, 2] position at the last event test
    prev_row: np.ndarray  # int64[A] the row it was tested on (-1: none yet)
    route_index: np.ndarray  # int64[A] nearest route point
    route_progress: np.ndarray  # float64[A] arc length reached along the route
    progress_delta: np.ndarray  # float64[A] progress of the last step
    # per episode
    episode_capacity: int  # rows of each episode's block
    episode_agent_start: np.ndarray  # int64[B + 1] first agent of each episode
    episode_map: np.ndarray  # int64[B] map of each episode in the stack
    episode_step: np.ndarray  # int64[B] steps taken
    episode_limit: np.ndarray  # int64[B] steps allowed
    terminate_on: np.ndarray  # bool[B, NUM_EVENTS] events that end an agent's episode
    not_moving_seconds: np.ndarray  # float64[B]
    not_moving_distance: np.ndarray  # float64[B]
    via_colour: np.ndarray  # int8[B, L] signal colour of each junction lane
    dt: float


for _record in (Lanes, SimTables):
    declare(_record)


@njit(nogil=True)
def freeze(fields):  # pragma: no cover - compiled
    """The frozen record of one of this module's records (see ``smarts.records``)."""
    return freeze_fields(fields)


def lanes_of(road_map) -> Lanes:
    """A road map's ``Lanes`` (its own arrays)."""
    m = road_map
    return Lanes(
        length=m.lane_length, width=m.lane_width, speed_limit=m.lane_speed_limit, road=m.lane_road,
        index=m.lane_index, internal=m.lane_internal, left=m.lane_left, right=m.lane_right,
        succ_offsets=m.succ_offsets, succ=m.succ, point_offsets=m.lanepoint_offsets, points=m.lanepoints,
        point_s=m.lanepoint_s, point_heading=m.lanepoint_heading,
    )  # fmt: skip


def lanes_record(road_map):
    """A road map's frozen ``Lanes``, built at the first call and kept on the map (maps do not
    change once compiled)."""
    frozen = road_map.__dict__.get("_lanes_record")
    if frozen is None:
        frozen = road_map.__dict__["_lanes_record"] = freeze(lanes_of(road_map))
    return frozen


def sim_tables(sim):
    """``sim``'s frozen ``SimTables``, built at the first call and kept on the simulation (with
    the tuple it was made from, ``sim._sim_tables_fields``)."""
    frozen = sim.__dict__.get("_sim_tables")
    if frozen is None:
        fields = sim.__dict__["_sim_tables_fields"] = tables_of(sim)
        frozen = sim.__dict__["_sim_tables"] = freeze(fields)
    return frozen


def tables_of(sim) -> SimTables:
    """``sim``'s ``SimTables`` (its own arrays)."""
    ma, st, t, rm = sim.mission_arrays, sim.map_stack, sim.table, sim.road_map
    g = sim.grids
    return SimTables(
        data=t.data, alive=t.alive, row_map=sim.row_map, lane=t.lane, role=t.role, vtype=t.vtype, anchor=sim.not_moving.anchor,
        anchor_time=sim.not_moving.anchor_time,
        lane_length=rm.lane_length, lane_width=rm.lane_width, lane_speed_limit=rm.lane_speed_limit,
        lane_road=rm.lane_road, lane_index=rm.lane_index, lane_internal=rm.lane_internal,
        lane_succ_offsets=rm.succ_offsets,
        grid_table=g.table, grid_offsets=g.offsets, grid_segs=g.segs, grid_cell_base=g.cell_base, grid_ny=g.ny,
        grid_origin=g.origin, grid_inv_cell=g.inv_cell, grid_cell_max=g.cell_max,
        raster_flat=st.raster_flat, raster_base=st.raster_base, raster_width=st.raster_width,
        raster_origin=st.raster_origin, raster_inv_res=st.raster_inv_res, raster_cell_max=st.raster_cell_max,
        flat_paths=ma.flat_paths, flat_valid=ma.flat_valid, stride=int(ma.stride), path_len=ma.path_len,
        path_s=ma.path_s, route_length=ma.route_length, on_route_road=ma.on_route_road, goal_kind=ma.goal_kind,
        goal_xy=ma.goal_xy, goal_radius=ma.goal_radius, goal_road=ma.goal_road, goal_lane=ma.goal_lane,
        goal_s=ma.goal_s, goal_gate=ma.goal_gate, signal_via=ma.signal_via.reshape(-1),
        signal_s=ma.signal_s.reshape(-1),
        agent_episode=sim.agent_episode, agent_active=sim.agent_active, agent_row=sim.agent_row,
        agent_events=sim.agent_events, agent_done=sim.agent_done,
        prev_xy=sim.agent_prev_xy, prev_row=sim.agent_prev_row, route_index=sim.route_index,
        route_progress=sim.route_progress, progress_delta=sim.route_progress_delta,
        episode_capacity=int(sim.episode_capacity), episode_agent_start=sim.episode_agent_start,
        episode_map=sim.episode_map, episode_step=sim.episode_step, episode_limit=sim.episode_limit,
        terminate_on=sim.terminate_on, not_moving_seconds=sim.not_moving_seconds,
        not_moving_distance=sim.not_moving_distance, via_colour=sim.via_colour,
        dt=float(sim.dt),
    )  # fmt: skip
