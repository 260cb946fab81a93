"""The step of the built-in traffic: every episode's ``BuiltinTrafficProvider`` in one compiled call.

The simulation steps every built-in traffic provider through this batch stage (the provider's
``batch_stage``), whether it runs one episode or thousands. Each episode keeps its own provider
(its departures, random stream, vehicle ids), but the provider's per-row state arrays are views
into stacked ``[providers, ...]`` blocks owned here, so one step of all of them is: one map projection of every other road user of every
episode, one compiled loop that hands each episode's rows to the provider's own kernels
(``build_occupancy``, ``step_vehicles``) on its block of the table, then Python only for the few
episodes where a vehicle arrives or a departure is due. Episodes with equal traffic specs on the
same map share route tables (built alike, so equal). Each such set's route and junction tables
are concatenated with the others' (``RouteSets``): the compiled loop hands every provider a view of
its own set's part, so one call covers every set, whatever the specs and maps.

The kernel reads three records made once (``StageState``: these blocks and the loop's own
outputs; the map's ``LaneGraph``; the ``RouteSets``) and this step's values beside them.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

import smarts.traffic.builtin.kernels as K
from smarts.compiled import njit
from smarts.core.simulation import Simulation
from smarts.records import declare, freeze_fields, view


class StageState(NamedTuple):
    """The stage's blocks, stacked over its providers (``[m, ...]``), and what its kernel writes
    for the Python part of the step."""

    members: np.ndarray  # int64[m] providers, set by set
    set_of: np.ndarray  # int64[m] each provider's set (its part of the RouteSets)
    episode: np.ndarray  # int64[m] each provider's episode
    cap: int  # rows per episode
    si: np.ndarray  # int64[m, NUM_INT_STATE, cap] (each provider's RowState: si, st, pa, mine)
    st: np.ndarray  # float64[m, NUM_FLOAT_STATE, cap]
    pa: np.ndarray  # float64[m, NUM_PARAMS, cap]
    mine: np.ndarray  # bool[m, cap]
    acc: np.ndarray  # float64[m, cap] (each provider's Decisions: acc ... arrived)
    guard: np.ndarray  # float64[m, cap]
    change: np.ndarray  # int64[m, cap]
    turn: np.ndarray  # int64[m, cap]
    arrived: np.ndarray  # bool[m, cap]
    raw_lane: np.ndarray  # int64[m, 3 cap] (each provider's RawEntries)
    raw_f: np.ndarray  # float64[m, 3, 3 cap] rows s, half, v
    raw_row: np.ndarray  # int64[m, 3 cap]
    raw_kind: np.ndarray  # int64[m, 3 cap]
    lane_off: np.ndarray  # int64[m, L + 1] (each provider's Occupancy)
    e_f: np.ndarray  # float64[m, 3, 3 cap] rows s, half, v
    e_row: np.ndarray  # int64[m, 3 cap]
    e_kind: np.ndarray  # int64[m, 3 cap]
    own_rows: np.ndarray  # int64[m, cap] out: each provider's own rows (episode rows, ascending) ...
    own_count: np.ndarray  # int64[m] ... the first own_count[k] of them
    f_lo: np.ndarray  # int64[m] out: each provider's part of this step's other rows ...
    f_hi: np.ndarray  # int64[m]
    f_local: np.ndarray  # int64[rows] ... and those rows in its episode's numbering
    arrivals: np.ndarray  # bool[m] out: a vehicle of the provider arrived this step


declare(StageState)


@njit(nogil=True)
def _freeze(fields):  # pragma: no cover - compiled
    """The frozen record of this module's records (see ``smarts.records``)."""
    return freeze_fields(fields)


class BuiltinTrafficStage:
    """The batch stage that steps the built-in traffic providers ``members`` (episode, provider)
    of ``sim``'s episodes."""

    def __init__(self, sim: Simulation, members: list[tuple[int, object]]):
        self.episode = np.array([b for b, _ in members], dtype=np.int64)
        self.provider = [p for _, p in members]
        m, cap, lanes = len(members), sim.episode_capacity, sim.road_map.num_lanes
        # Sets of episodes with equal traffic specs on one map share route tables (built alike, so equal).
        sets: dict[int, list[int]] = {}
        specs: list = []
        for k, p in enumerate(self.provider):
            for s, (road_map, spec) in enumerate(specs):
                if road_map is p.map and spec == p.traffic:
                    sets[s].append(k)
                    break
            else:
                sets[len(specs)] = [k]
                specs.append((p.map, p.traffic))
        set_members = [np.array(v, dtype=np.int64) for v in sets.values()]
        set_of = np.zeros(m, dtype=np.int64)  # each provider's set: its part of the tables
        for t, members_of_set in enumerate(set_members):
            set_of[members_of_set] = t
        self.state = StageState(
            members=np.concatenate(set_members) if set_members else np.zeros(0, dtype=np.int64),
            set_of=set_of, episode=self.episode, cap=int(cap),
            si=np.zeros((m, K.NUM_INT_STATE, cap), dtype=np.int64), st=np.zeros((m, K.NUM_FLOAT_STATE, cap)),
            pa=np.zeros((m, K.NUM_PARAMS, cap)), mine=np.zeros((m, cap), dtype=bool),
            acc=np.zeros((m, cap)), guard=np.zeros((m, cap)), change=np.zeros((m, cap), dtype=np.int64),
            turn=np.zeros((m, cap), dtype=np.int64), arrived=np.zeros((m, cap), dtype=bool),
            raw_lane=np.zeros((m, 3 * cap), dtype=np.int64), raw_f=np.zeros((m, 3, 3 * cap)),
            raw_row=np.zeros((m, 3 * cap), dtype=np.int64), raw_kind=np.zeros((m, 3 * cap), dtype=np.int64),
            lane_off=np.zeros((m, lanes + 1), dtype=np.int64), e_f=np.zeros((m, 3, 3 * cap)),
            e_row=np.zeros((m, 3 * cap), dtype=np.int64), e_kind=np.zeros((m, 3 * cap), dtype=np.int64),
            own_rows=np.zeros((m, cap), dtype=np.int64), own_count=np.zeros(m, dtype=np.int64),
            f_lo=np.zeros(m, dtype=np.int64), f_hi=np.zeros(m, dtype=np.int64),
            f_local=np.zeros(sim.episodes * cap, dtype=np.int64), arrivals=np.zeros(m, dtype=bool),
        )  # fmt: skip
        self.frozen_state = _freeze(self.state)
        self.mine = self.state.mine
        for k, p in enumerate(self.provider):
            p.capacity = cap  # its reset keeps these views instead of allocating
            p.si, p.st, p.pa, p.mine = self.state.si[k], self.state.st[k], self.state.pa[k], self.state.mine[k]
        self.members = self.state.members
        self.tables = _RouteSets([self.provider[members_of_set[0]] for members_of_set in set_members])
        self.next_due = np.zeros(m)  # earliest departure time of each provider (inf: none)
        self.waiting = np.zeros(m, dtype=bool)  # a departure waits for room
        self.member_of = np.full(sim.episodes, -1, dtype=np.int64)
        self.member_of[self.episode] = np.arange(m)
        self._union_mine = np.zeros(sim.episodes * cap, dtype=bool)
        self._rows_of_members = np.zeros(sim.episodes * cap, dtype=bool)
        self._rows_of_members.reshape(sim.episodes, cap)[self.episode] = True

    def after_reset(self, sim: Simulation, episodes: np.ndarray) -> None:
        for k in self.member_of[episodes]:
            if k >= 0:
                self._note_departures(k)

    def _note_departures(self, k: int) -> None:
        p = self.provider[k]
        self.next_due[k] = p.next_time.min() if p.next_time.size else np.inf
        self.waiting[k] = bool(p.pending.any())

    def step(self, sim: Simulation, dt: float) -> None:
        cap = sim.episode_capacity
        table = sim.table
        union_mine = self._union_mine
        union_mine.reshape(sim.episodes, cap)[self.episode] = self.mine
        foreign = np.flatnonzero(table.alive & ~union_mine & self._rows_of_members)
        if foreign.size:
            proj = sim.project_rows(foreign)
            f_lane, f_s, f_t = proj.lane.astype(np.int64), proj.s, proj.t
            f_dh = table.heading[foreign] - proj.lane_heading
        else:
            f_lane, f_s, f_t, f_dh = np.zeros(0, np.int64), np.zeros(0), np.zeros(0), np.zeros(0)
        state = self.state
        if self.members.size:
            self.tables.check_current()
            _step_episodes(
                self.frozen_state, self.provider[0].frozen_lanes, self.tables.frozen, table.data, sim.via_colour,
                sim.episode_step, dt, foreign, f_lane, f_s, f_t, f_dh,
            )  # fmt: skip
        for k in np.flatnonzero(state.arrivals).tolist():
            b = int(self.episode[k])
            mine_rows = state.own_rows[k, : state.own_count[k]]
            gone = mine_rows[state.arrived[k, : mine_rows.size]]
            sim.views[b].table.remove(gone)
            self.mine[k, gone] = False
        time = sim.episode_time[self.episode]
        due = np.flatnonzero((self.next_due <= time + 1e-9) | self.waiting)
        for k in due.tolist():
            b, p = int(self.episode[k]), self.provider[k]
            view = sim.views[b]
            lo, hi = int(state.f_lo[k]), int(state.f_hi[k])
            p._depart(view, view.time, state.f_local[lo:hi], f_lane[lo:hi], f_s[lo:hi])
            self._note_departures(k)
        # (each provider's own step_count is not kept: its kernels get the episode's step here)


class _RouteSets:
    """The ``RouteSets`` record of several sets of providers (one provider of each): their route and
    junction tables concatenated, frozen for the kernel. The lane arrays are the same for every
    set (one map or one stack of maps)."""

    def __init__(self, providers: list):
        self.providers = providers
        per_set = [p.route_tables() for p in providers]
        self._packed = [t.slot_int for t in per_set]
        if not per_set:
            self.fields = self.frozen = None
            return
        self.fields = K.RouteSets(
            tables=K.Routes(*(np.ascontiguousarray(np.concatenate(parts, axis=-1)) for parts in zip(*per_set))),
            bounds=K.Routes(*(np.concatenate([[0], np.cumsum([a.shape[-1] for a in parts])]).astype(np.int64)
                              for parts in zip(*per_set))),
        )  # fmt: skip
        self.frozen = K.freeze(self.fields)

    def check_current(self) -> None:
        """Routes are added when a provider is built; should one add more later, pack again."""
        for p, packed in zip(self.providers, self._packed):
            if p.routes.slot_int is not packed:
                self.__init__(self.providers)
                return


@njit(nogil=True)
def _step_episodes(
    frozen_state,
    frozen_lanes,
    frozen_sets,
    data,
    via_colour,
    episode_step,
    dt,
    foreign,
    f_lane,
    f_s,
    f_t,
    f_dh,
):  # pragma: no cover - compiled
    """``BuiltinTrafficProvider.step``'s compiled part for each member, on its block of rows, with
    its set's route and junction tables (views into the concatenated ones, see ``RouteSets``).

    ``foreign`` (ascending table rows) are this step's other road users of the members' episodes,
    projected on ``f_lane`` at ``f_s``, ``f_t`` with heading ``f_dh`` off the lane's. Writes each
    member's own rows, its share of ``foreign`` and whether a vehicle of it arrived into the
    ``StageState`` for the Python part of the step."""
    stage, lanes, sets = view(frozen_state), view(frozen_lanes), view(frozen_sets)
    members, set_of, episode, cap = stage.members, stage.set_of, stage.episode, stage.cap
    f_local, f_lo, f_hi = stage.f_local, stage.f_lo, stage.f_hi
    own_rows, own_count, arrivals = stage.own_rows, stage.own_count, stage.arrivals
    for k in range(episode.shape[0]):
        start = episode[k] * cap
        lo, hi = np.searchsorted(foreign, start), np.searchsorted(foreign, start + cap)
        f_lo[k], f_hi[k] = lo, hi
        for i in range(lo, hi):
            f_local[i] = foreign[i] - start
        n = 0
        for r in range(cap):
            if stage.mine[k, r]:
                own_rows[k, n] = r
                n += 1
        own_count[k] = n
        arrivals[k] = False
    for q in range(members.shape[0]):
        k = members[q]
        if own_count[k] == 0:
            continue
        t = set_of[k]
        routes = K.set_routes(sets, t)
        b = episode[k]
        own = own_rows[k, : own_count[k]]
        lo, hi = f_lo[k], f_hi[k]
        others = K.Others(rows=f_local[lo:hi], lane=f_lane[lo:hi], s=f_s[lo:hi], t=f_t[lo:hi], dh=f_dh[lo:hi])
        block = data[:, b * cap : (b + 1) * cap]
        state = K.RowState(si=stage.si[k], st=stage.st[k], pa=stage.pa[k], mine=stage.mine[k])
        raw = K.RawEntries(lane=stage.raw_lane[k], s=stage.raw_f[k, 0], half=stage.raw_f[k, 1], v=stage.raw_f[k, 2],
                           row=stage.raw_row[k], kind=stage.raw_kind[k])  # fmt: skip
        occ = K.Occupancy(lane_off=stage.lane_off[k], s=stage.e_f[k, 0], half=stage.e_f[k, 1], v=stage.e_f[k, 2],
                          row=stage.e_row[k], kind=stage.e_kind[k])  # fmt: skip
        out = K.Decisions(acc=stage.acc[k], guard=stage.guard[k], change=stage.change[k], turn=stage.turn[k],
                          arrived=stage.arrived[k])  # fmt: skip
        K.build_occupancy(own, others, block, state, lanes, routes, raw, occ)
        K.step_vehicles(own, block, state, out, occ, lanes, routes, via_colour[b], dt, episode_step[b])
        for i in range(own.shape[0]):
            if out.arrived[i]:
                arrivals[k] = True
                break
