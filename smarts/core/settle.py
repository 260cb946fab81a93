"""What the step does once the providers have moved the vehicles, in one compiled call: the live
rows, each row projected onto its episode's map, the route progress of every active agent and the
events of every episode.

Why one call: at one agent each of these stages costs less than calling it from Python (the
arrays gathered, the projections allocated and written back column by column, a record typed per
call), so a step paid more for the calls than for the work. ``settle`` reads and writes the
simulation's own arrays through its ``SimTables`` (``smarts.core.sim_records``) and runs the same
compiled code per row and per agent as the separate stages (``project_point``, ``route_progress``,
``episode_events``), so their results are bit for bit those of the stages run one by one.
"""

from __future__ import annotations

import math

import numpy as np

from smarts.compiled import njit
from smarts.core.events import episode_events, event_tables
from smarts.core.vehicle_table import COLUMN
from smarts.maps.projection import Grids, project_point

ROUTE_WINDOW_BACK = 2  # route points searched behind the last match
ROUTE_WINDOW_AHEAD = 10  # ... and ahead of it (more than the farthest one-step move at ~1 m spacing)


@njit(nogil=True)
def settle(tables, agents, episode_time):  # pragma: no cover - compiled
    """After the providers: project every live row, advance the route progress of ``agents`` (the
    active agents, ascending) and test the events of every episode at its clock
    (``episode_time[b]``); returns the live rows (ascending). ``tables``: the frozen ``SimTables``."""
    t = tables
    alive = np.flatnonzero(t.alive)
    project_rows(t, alive)
    rows = t.agent_row[agents]
    route_progress(t, agents, rows, False)
    events_of_episodes(t, alive, agents, rows, episode_time)
    return alive


@njit(nogil=True)
def advance_clocks(episode_step, episode_time, dt):  # pragma: no cover - compiled
    """One more step on every episode's clock: ``time = step * dt`` (no drift from summing dt).
    Compiled: two numpy operations on arrays of one episode cost more than a call."""
    for b in range(episode_step.shape[0]):
        episode_step[b] += 1
        episode_time[b] = episode_step[b] * dt


@njit(nogil=True)
def project_rows(t, rows):  # pragma: no cover - compiled
    """Lane, s, t, lane heading and distance of ``rows``, each on its episode's map."""
    grids = Grids(t.grid_table, t.grid_offsets, t.grid_segs, t.grid_cell_base, t.grid_ny, t.grid_origin,
                  t.grid_inv_cell, t.grid_cell_max)  # fmt: skip
    data, lane, row_map = t.data, t.lane, t.row_map
    for r in rows:
        ln, s, offset, heading, distance = project_point(grids, row_map[r], data[_X, r], data[_Y, r], data[_H, r], True)
        lane[r] = ln
        data[_S, r], data[_T, r], data[_LANE_HEADING, r], data[_LANE_DISTANCE, r] = s, offset, heading, distance


@njit(nogil=True)
def events_of_episodes(t, alive, agents, rows, episode_time):  # pragma: no cover - compiled
    """Clear the events of agents no longer active, then ``episode_events`` of each episode with
    only its own live rows and agents (``alive`` and ``agents`` ascending)."""
    events, active = t.agent_events, t.agent_active
    for a in range(active.shape[0]):
        if not active[a]:
            events[a, :] = False
    et = event_tables(t)
    n_episodes = episode_time.shape[0]
    if n_episodes == 1:
        if agents.shape[0]:
            episode_events(et, alive, agents, rows, 0, episode_time[0])
        return
    cap, start = t.episode_capacity, t.episode_agent_start
    row_lo = 0
    agent_lo = 0
    for b in range(n_episodes):
        row_hi = row_lo
        while row_hi < alive.shape[0] and alive[row_hi] < (b + 1) * cap:
            row_hi += 1
        agent_hi = agent_lo
        while agent_hi < agents.shape[0] and agents[agent_hi] < start[b + 1]:
            agent_hi += 1
        if agent_hi > agent_lo:
            episode_events(
                et, alive[row_lo:row_hi], agents[agent_lo:agent_hi], rows[agent_lo:agent_hi], b, episode_time[b]
            )
        row_lo, agent_lo = row_hi, agent_hi


@njit(nogil=True)
def route_progress(tables, agents, rows, first):  # pragma: no cover - compiled
    """Nearest route point in a window around the last one, and the arc length reached (into
    ``tables``, the simulation's frozen ``SimTables``)."""
    data, flat_paths, stride, path_len = tables.data, tables.flat_paths, tables.stride, tables.path_len
    path_s, route_length = tables.path_s, tables.route_length
    route_index, route_progress, delta = tables.route_index, tables.route_progress, tables.progress_delta
    for i in range(agents.shape[0]):
        a, r = agents[i], rows[i]
        x, y = data[_X, r], data[_Y, r]
        last = path_len[a] - 1
        if first:
            lo, hi = 0, min(4 * ROUTE_WINDOW_AHEAD, last)
        else:
            lo = max(route_index[a] - ROUTE_WINDOW_BACK, 0)
            hi = min(route_index[a] + ROUTE_WINDOW_AHEAD, last)
        best, best_d2 = lo, np.inf
        for k in range(lo, hi + 1):
            p = flat_paths[a * stride + k, 0]
            d2 = (p[0] - x) ** 2 + (p[1] - y) ** 2
            if d2 < best_d2:
                best, best_d2 = k, d2
        p = flat_paths[a * stride + best, 0]
        along = (x - p[0]) * math.cos(p[2]) + (y - p[1]) * math.sin(p[2])
        progress = min(max(path_s[a, best] + along, 0.0), route_length[a])
        delta[a] = 0.0 if first else progress - route_progress[a]
        route_progress[a] = progress
        route_index[a] = best


_X, _Y, _H = COLUMN["x"], COLUMN["y"], COLUMN["heading"]
_S, _T, _LANE_HEADING, _LANE_DISTANCE = COLUMN["s"], COLUMN["t"], COLUMN["lane_heading"], COLUMN["lane_distance"]
