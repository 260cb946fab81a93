"""The step of the built-in traffic: every episode's ``BuiltinTrafficProvider`` in one compiled call.

The simulation steps every built-in traffic provider through this batch stage (the provider's
``batch_stage``), whether it runs one episode or thousands. Each episode keeps its own provider
(its departures, random stream, vehicle ids), but the provider's per-row state arrays are views
into stacked ``[providers, ...]`` blocks owned here, so one step of all of them is: one map projection of every other road user of every
episode, one compiled loop that hands each episode's rows to the provider's own kernels
(``build_occupancy``, ``step_vehicles``) on its block of the table, then Python only for the few
episodes where a vehicle arrives or a departure is due. Episodes with equal traffic specs on the
same map share route tables (built alike, so equal). Each such set's route and junction tables
are concatenated with the others' (``_Tables``): the compiled loop hands every provider a view of
its own set's part, so one call covers every set, whatever the specs and maps.
"""

from __future__ import annotations

import numba
import numpy as np

import smarts.traffic.builtin.kernels as K
from smarts.core.simulation import Simulation


class BuiltinTrafficStage:
    """The batch stage that steps the built-in traffic providers ``members`` (episode, provider)
    of ``sim``'s episodes."""

    def __init__(self, sim: Simulation, members: list[tuple[int, object]]):
        self.episode = np.array([b for b, _ in members], dtype=np.int64)
        self.provider = [p for _, p in members]
        m, cap, lanes = len(members), sim.episode_capacity, sim.road_map.num_lanes
        self.si = np.zeros((m, K.NUM_INT_STATE, cap), dtype=np.int64)
        self.st = np.zeros((m, K.NUM_FLOAT_STATE, cap))
        self.pa = np.zeros((m, K.NUM_PARAMS, cap))
        self.mine = np.zeros((m, cap), dtype=bool)
        self.arrived = np.zeros((m, cap), dtype=bool)
        self.acc = np.zeros((m, cap))
        self.guard = np.zeros((m, cap))
        self.change = np.zeros((m, cap), dtype=np.int64)
        self.turn = np.zeros((m, cap), dtype=np.int64)
        self.raw_lane = np.zeros((m, 3 * cap), dtype=np.int64)
        self.raw_row = np.zeros((m, 3 * cap), dtype=np.int64)
        self.raw_kind = np.zeros((m, 3 * cap), dtype=np.int64)
        self.raw_f = np.zeros((m, 3, 3 * cap))
        self.e_row = np.zeros((m, 3 * cap), dtype=np.int64)
        self.e_kind = np.zeros((m, 3 * cap), dtype=np.int64)
        self.e_f = np.zeros((m, 3, 3 * cap))
        self.lane_off = np.zeros((m, lanes + 1), dtype=np.int64)
        for k, p in enumerate(self.provider):
            p.capacity = cap  # its reset keeps these views instead of allocating
            for name in ("si", "st", "pa", "mine", "arrived", "acc", "guard", "change", "turn", "raw_lane",
                         "raw_row", "raw_kind", "raw_f", "e_row", "e_kind", "e_f", "lane_off"):  # fmt: skip
                setattr(p, name, getattr(self, name)[k])
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
        self.set_of = np.zeros(m, dtype=np.int64)  # each provider's set: its part of the tables
        for t, members in enumerate(set_members):
            self.set_of[members] = t
        self.members = np.concatenate(set_members) if set_members else np.zeros(0, dtype=np.int64)
        self.tables = _Tables([self.provider[members[0]] for members in set_members])
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
        own = np.flatnonzero(union_mine)
        starts = self.episode * cap
        f_lo, f_hi = np.searchsorted(foreign, starts), np.searchsorted(foreign, starts + cap)
        o_lo, o_hi = np.searchsorted(own, starts), np.searchsorted(own, starts + cap)
        f_local = foreign - np.repeat(starts, f_hi - f_lo)
        own_local = own - np.repeat(starts, o_hi - o_lo)
        arrivals = np.zeros(len(self.provider), dtype=bool)
        if self.members.size:
            p, tb = self.provider[0], self.tables
            tb.check_current()
            _step_episodes(
                self.members, self.set_of, self.episode, cap, o_lo, o_hi, own_local, f_lo, f_hi, f_local, f_lane,
                f_s, f_t, f_dh, table.data, self.si, self.st, self.pa, self.mine, self.arrived, self.acc, self.guard,
                self.change, self.turn, self.lane_off, self.raw_lane, self.raw_f, self.raw_row, self.raw_kind,
                self.e_f, self.e_row, self.e_kind, p.lane_f, p.lane_lr, p.pred_off, p.pred, p.point_off, p.point_s,
                p.points, p.seg_heading, *tb.arrays, *tb.bounds, sim.via_colour, dt, sim.episode_step, arrivals,
            )  # fmt: skip
        for k in np.flatnonzero(arrivals).tolist():
            b, p = int(self.episode[k]), self.provider[k]
            mine_rows = own_local[o_lo[k]:o_hi[k]]
            gone = mine_rows[self.arrived[k, : mine_rows.size]]
            sim.views[b].table.remove(gone)
            self.mine[k, gone] = False
        time = sim.episode_time[self.episode]
        due = np.flatnonzero((self.next_due <= time + 1e-9) | self.waiting)
        for k in due.tolist():
            b, p = int(self.episode[k]), self.provider[k]
            view = sim.views[b]
            lo, hi = f_lo[k], f_hi[k]
            p._depart(view, view.time, f_local[lo:hi], f_lane[lo:hi], f_s[lo:hi])
            self._note_departures(k)
        # (each provider's own step_count is not kept: its kernels get the episode's step here)


class _Tables:
    """The route tables (``slot_int``, ``slot_cost``) and junction tables of several sets of
    providers, each array concatenated along its last axis over the sets, with per-set bounds:
    set ``t``'s own array is ``array[..., bound[t]:bound[t + 1]]`` (indices inside it stay the
    set's own). The lane arrays are the same for every set (one map or one stack of maps)."""

    def __init__(self, providers: list):
        self.providers = providers
        self._packed = [p.routes.slot_int for p in providers]
        per_set = [self._of(p) for p in providers]
        if not per_set:
            self.arrays, self.bounds = (), ()
            return
        self.arrays = tuple(np.ascontiguousarray(np.concatenate([t[i] for t in per_set], axis=-1))
                            for i in range(len(per_set[0])))  # fmt: skip
        self.bounds = tuple(np.concatenate([[0], np.cumsum([t[i].shape[-1] for t in per_set])]).astype(np.int64)
                            for i in range(len(per_set[0])))  # fmt: skip

    @staticmethod
    def _of(p) -> tuple:
        jt = p.junctions
        return (p.routes.slot_int, p.routes.slot_cost, p.conn_int, jt.conn_length, jt.lanes_offsets, jt.lanes,
                jt.conn_of_lane, jt.offset_of_lane, jt.foe_offsets, jt.foe, jt.foe_kind, jt.zone)  # fmt: skip

    def check_current(self) -> None:
        """Routes are added when a provider is built; should one add more later, pack again."""
        for p, packed in zip(self.providers, self._packed):
            if p.routes.slot_int is not packed:
                self.__init__(self.providers)
                return


@numba.njit(cache=True, nogil=True)
def _step_episodes(
    members, set_of, episode, cap, o_lo, o_hi, own_local, f_lo, f_hi, f_local, f_lane, f_s, f_t, f_dh,
    data, si, st, pa, mine, arrived, acc, guard, change, turn, lane_off, raw_lane, raw_f, raw_row, raw_kind,
    e_f, e_row, e_kind, lane_f, lane_lr, pred_off, pred, point_off, point_s, points, seg_heading,
    slot_int_all, slot_cost_all, conn_int_all, conn_length_all, lanes_offsets_all, lanes_all, conn_of_lane_all,
    offset_of_lane_all, foe_offsets_all, foe_all, foe_kind_all, zone_all,
    b_slot_int, b_slot_cost, b_conn_int, b_conn_length, b_lanes_offsets, b_lanes, b_conn_of_lane,
    b_offset_of_lane, b_foe_offsets, b_foe, b_foe_kind, b_zone, via_colour, dt, episode_step, arrivals,
):  # pragma: no cover - compiled
    """``BuiltinTrafficProvider.step``'s compiled part for each member, on its block of rows, with
    its set's route and junction tables (views into the concatenated ones, see ``_Tables``)."""
    for q in range(members.shape[0]):
        k = members[q]
        if o_hi[k] == o_lo[k]:
            continue
        t = set_of[k]
        slot_int = slot_int_all[:, b_slot_int[t]:b_slot_int[t + 1]]
        slot_cost = slot_cost_all[b_slot_cost[t]:b_slot_cost[t + 1]]
        conn_int = conn_int_all[:, b_conn_int[t]:b_conn_int[t + 1]]
        conn_length = conn_length_all[b_conn_length[t]:b_conn_length[t + 1]]
        lanes_offsets = lanes_offsets_all[b_lanes_offsets[t]:b_lanes_offsets[t + 1]]
        lanes = lanes_all[b_lanes[t]:b_lanes[t + 1]]
        conn_of_lane = conn_of_lane_all[b_conn_of_lane[t]:b_conn_of_lane[t + 1]]
        offset_of_lane = offset_of_lane_all[b_offset_of_lane[t]:b_offset_of_lane[t + 1]]
        foe_offsets = foe_offsets_all[b_foe_offsets[t]:b_foe_offsets[t + 1]]
        foe = foe_all[b_foe[t]:b_foe[t + 1]]
        foe_kind = foe_kind_all[b_foe_kind[t]:b_foe_kind[t + 1]]
        zone = zone_all[:, b_zone[t]:b_zone[t + 1]]
        b = episode[k]
        own = own_local[o_lo[k]:o_hi[k]]
        lo, hi = f_lo[k], f_hi[k]
        block = data[:, b * cap:(b + 1) * cap]
        K.build_occupancy(
            own, f_local[lo:hi], f_lane[lo:hi], f_s[lo:hi], f_t[lo:hi], f_dh[lo:hi], block, si[k], st[k],
            slot_int, lane_f, lane_lr, pred_off, pred, lane_off[k], raw_lane[k], raw_f[k, 0], raw_f[k, 1],
            raw_f[k, 2], raw_row[k], raw_kind[k], e_f[k, 0], e_f[k, 1], e_f[k, 2], e_row[k], e_kind[k],
        )  # fmt: skip
        K.step_vehicles(
            own, block, si[k], st[k], pa[k], mine[k], arrived[k], acc[k], guard[k], change[k], turn[k],
            lane_off[k], e_f[k, 0], e_f[k, 1], e_f[k, 2], e_row[k], e_kind[k], lane_f, lane_lr, point_off,
            point_s, points, seg_heading, pred_off, pred, slot_int, slot_cost, conn_int, conn_length,
            lanes_offsets, lanes, conn_of_lane, offset_of_lane, foe_offsets, foe, foe_kind, zone, via_colour[b],
            dt, episode_step[b],
        )  # fmt: skip
        for i in range(own.shape[0]):
            if arrived[k, i]:
                arrivals[k] = True
                break
