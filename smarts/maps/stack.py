"""Several road maps as one lane index space, so one batch of episodes can run on all of them.

``stack_maps(maps)`` concatenates the lane-indexed arrays of the maps (lanes, centre lines, lane
graph, segments, lanepoints, junction connections, signals), shifting every index by its map's
*base* (map ``m``'s lane ``i`` becomes lane ``lane_base[m] + i``; roads, segments, points and
signals likewise). Everything that only follows lane indices (controllers, events, observations,
rewards, route tables) then works on the stacked map unchanged.

Space does not stack: the maps overlap in world coordinates. Each map therefore gets a *window*:
a ``RoadMap`` sharing the stacked lane arrays but with that map's own segment grid, drivable
raster, bounds, junction connections and signals, and with lane and road ids that look up into
its own maps' stacked indices. A window is a complete map (projection, routing, mission
resolution, traffic and signals run on it and give stacked indices). ``MapStack.project`` projects
points each on its own map's grid in one compiled call.

Shifting indices is exact and keeps their order, and each point is compared with the same
segments in the same order as on its own map, so results are bit-identical to the single map's
(up to the index shift).
"""

from __future__ import annotations

import copy
import hashlib
from collections.abc import Sequence

import numpy as np

from smarts.maps.drivable import raster_lookup
from smarts.maps.projection import Grids, LaneProjection, _Index, freeze, project_on_grids, projection_index
from smarts.maps.road_map import RoadMap


def _csr(offsets: Sequence[np.ndarray]) -> np.ndarray:
    """CSR offsets of concatenated CSR arrays (each starting at 0)."""
    parts, base = [np.zeros(1, dtype=np.int64)], 0
    for off in offsets:
        parts.append(np.asarray(off[1:], dtype=np.int64) + base)
        base += int(off[-1])
    return np.concatenate(parts)


def _shifted(values: np.ndarray, base: int) -> np.ndarray:
    """Indices shifted by ``base``; -1 (none) stays -1."""
    values = np.asarray(values)
    return np.where(values >= 0, values + base, values).astype(values.dtype)


class MapStack:
    """``maps`` stacked: ``combined`` (the lane index space), ``windows[m]`` (map ``m`` in it),
    and the bases of every map's indices (``lane_base``, ``road_base``, ``seg_base``)."""

    def __init__(self, maps: Sequence[RoadMap]):
        if not maps:
            raise ValueError("stack_maps needs at least one map")
        self.maps = list(maps)
        count = len(self.maps)
        self.lane_base = np.concatenate([[0], np.cumsum([m.num_lanes for m in self.maps])]).astype(np.int64)
        self.road_base = np.concatenate([[0], np.cumsum([len(m.road_ids) for m in self.maps])]).astype(np.int64)
        self.seg_base = np.concatenate([[0], np.cumsum([len(m.seg_lane) for m in self.maps])]).astype(np.int64)
        if count == 1:  # one map is its own stack: nothing is copied
            self.combined = self.maps[0]
            self.windows = [self.maps[0]]
        else:
            self.combined = self._combine()
            self.windows = [self._window(k) for k in range(count)]
        self._spatial_index()

    @property
    def num_maps(self) -> int:
        return len(self.maps)

    # ------------------------------------------------------------------ the stacked arrays
    def _lanes_of(self, k: int, values: np.ndarray) -> np.ndarray:
        return _shifted(values, int(self.lane_base[k]))

    def _conn_fields(self, k: int) -> dict:
        m = self.maps[k]
        return {
            "conn_from": self._lanes_of(k, m.conn_from), "conn_via": self._lanes_of(k, m.conn_via),
            "conn_to": self._lanes_of(k, m.conn_to), "conn_tls": m.conn_tls, "conn_link": m.conn_link,
            "conn_major": m.conn_major, "conn_dir": m.conn_dir,
            "tls_ids": list(m.tls_ids), "tls_offset": m.tls_offset, "tls_phase_offsets": m.tls_phase_offsets,
            "tls_phase_duration": m.tls_phase_duration, "tls_phase_state": m.tls_phase_state,
            "stop_sign_xy": m.stop_sign_xy, "stop_sign_lane": self._lanes_of(k, m.stop_sign_lane),
        }  # fmt: skip

    def _combine(self) -> RoadMap:
        maps, ks = self.maps, range(len(self.maps))
        cat = np.concatenate
        lanes = {name: cat([getattr(m, name) for m in maps]) for name in (
            "lane_index", "lane_width", "lane_speed_limit", "lane_length", "lane_sumo_length", "lane_internal",
            "points", "point_s", "seg_start", "seg_vec", "seg_len", "seg_heading", "seg_s0",
            "lanepoints", "lanepoint_s", "lanepoint_heading",
        )}  # fmt: skip
        conns = [self._conn_fields(k) for k in ks]
        tls_base = np.concatenate([[0], np.cumsum([len(m.tls_ids) for m in maps])])
        bounds = np.array([min(m.bounds[0] for m in maps), min(m.bounds[1] for m in maps),
                           max(m.bounds[2] for m in maps), max(m.bounds[3] for m in maps)])  # fmt: skip
        digest = hashlib.sha256("\0".join(m.content_hash for m in maps).encode()).hexdigest()
        combined = RoadMap(
            source=" + ".join(m.source for m in maps),
            content_hash=digest,
            lane_ids=[lane for m in maps for lane in m.lane_ids],
            road_ids=[road for m in maps for road in m.road_ids],
            lane_road=cat([_shifted(m.lane_road, int(self.road_base[k])) for k, m in enumerate(maps)]),
            lane_left=cat([self._lanes_of(k, m.lane_left) for k, m in enumerate(maps)]),
            lane_right=cat([self._lanes_of(k, m.lane_right) for k, m in enumerate(maps)]),
            lane_point_offsets=_csr([m.lane_point_offsets for m in maps]),
            succ_offsets=_csr([m.succ_offsets for m in maps]),
            succ=cat([self._lanes_of(k, m.succ) for k, m in enumerate(maps)]),
            pred_offsets=_csr([m.pred_offsets for m in maps]),
            pred=cat([self._lanes_of(k, m.pred) for k, m in enumerate(maps)]),
            seg_lane=cat([self._lanes_of(k, m.seg_lane) for k, m in enumerate(maps)]),
            # no space of its own: projection and on-road tests go through a window (see _refuse)
            grid_origin=np.zeros(2), grid_cell=1.0, grid_shape=(1, 1), grid_margin=0.0,
            grid_offsets=np.zeros(2, dtype=np.int64), grid_segs=np.zeros(0, dtype=np.int32),
            raster_origin=np.zeros(2), raster_resolution=1.0, drivable=np.zeros((1, 1), dtype=bool),
            lanepoint_offsets=_csr([m.lanepoint_offsets for m in maps]),
            bounds=bounds,
            junction_shapes=[s for m in maps for s in m.junction_shapes],
            conn_from=cat([c["conn_from"] for c in conns]), conn_via=cat([c["conn_via"] for c in conns]),
            conn_to=cat([c["conn_to"] for c in conns]),
            conn_tls=cat([_shifted(c["conn_tls"], int(tls_base[k])) for k, c in enumerate(conns)]),
            conn_link=cat([c["conn_link"] for c in conns]), conn_major=cat([c["conn_major"] for c in conns]),
            conn_dir=cat([c["conn_dir"] for c in conns]),
            tls_ids=[t for c in conns for t in c["tls_ids"]], tls_offset=cat([c["tls_offset"] for c in conns]),
            tls_phase_offsets=_csr([c["tls_phase_offsets"] for c in conns]),
            tls_phase_duration=cat([c["tls_phase_duration"] for c in conns]),
            tls_phase_state=cat([c["tls_phase_state"] for c in conns]),
            stop_sign_xy=cat([c["stop_sign_xy"] for c in conns]).reshape(-1, 2),
            stop_sign_lane=cat([c["stop_sign_lane"] for c in conns]),
            mark_kind=cat([m.mark_kind for m in maps]), mark_offsets=_csr([m.mark_offsets for m in maps]),
            mark_points=cat([m.mark_points for m in maps]).reshape(-1, 2),
            # ids repeat across maps: look them up in a window (keys here name the map)
            lane_index_of={f"{k}:{lane}": int(self.lane_base[k]) + i for k, m in enumerate(maps) for i, lane in enumerate(m.lane_ids)},
            road_index_of={f"{k}:{road}": int(self.road_base[k]) + i for k, m in enumerate(maps) for i, road in enumerate(m.road_ids)},
            **lanes,
        )  # fmt: skip
        _refuse_space(combined)
        return combined

    def _window(self, k: int) -> RoadMap:
        """Map ``k`` in the stacked index space (see the module docstring)."""
        m, window = self.maps[k], copy.copy(self.combined)
        window.__dict__ = dict(self.combined.__dict__)
        for name in ("_projection_index", "_raster_lookup", "_junction_table", "_route_road_tables"):
            window.__dict__.pop(name, None)
        window.source, window.content_hash = m.source, m.content_hash
        for name in ("grid_origin", "grid_cell", "grid_shape", "grid_margin", "raster_origin", "raster_resolution",
                     "drivable", "bounds", "junction_shapes", "mark_kind", "mark_offsets", "mark_points"):  # fmt: skip
            setattr(window, name, getattr(m, name))
        window.grid_offsets = m.grid_offsets
        window.grid_segs = _shifted(m.grid_segs, int(self.seg_base[k]))
        for name, value in self._conn_fields(k).items():
            setattr(window, name, value)
        lane0, road0 = int(self.lane_base[k]), int(self.road_base[k])
        window.lane_index_of = {lane: lane0 + i for lane, i in m.lane_index_of.items()}
        window.road_index_of = {road: road0 + i for road, i in m.road_index_of.items()}
        window.__dict__["_own_lanes"] = range(lane0, lane0 + m.num_lanes)
        window.__dict__["_own_roads"] = range(road0, road0 + len(m.road_ids))
        return window

    # ------------------------------------------------------------------ space, per map
    def _spatial_index(self) -> None:
        """Every window's projection grid over the one shared segment table, concatenated, and
        every map's drivable raster, for per-point lookups in one call."""
        grids = [projection_index(self.windows[0]).grids]
        for window in self.windows[1:]:
            ix = _Index(window, table=grids[0].table)
            window.__dict__["_projection_index"] = ix
            grids.append(ix.grids)
        self.grids = Grids(
            table=grids[0].table,
            offsets=_csr([g.offsets for g in grids]).astype(np.intp),
            segs=np.concatenate([g.segs for g in grids]).astype(np.intp),
            cell_base=np.concatenate([[0], np.cumsum([len(g.offsets) - 1 for g in grids[:-1]])]).astype(np.int64),
            **{
                name: np.concatenate([getattr(g, name) for g in grids])
                for name in ("ny", "origin", "inv_cell", "cell_max")
            },
        )
        self.frozen_grids = freeze(self.grids)  # what project_on_grids takes
        rasters = [raster_lookup(m) for m in self.maps]
        self.raster_flat = np.concatenate([r[4] for r in rasters])
        self.raster_base = np.concatenate([[0], np.cumsum([len(r[4]) for r in rasters])]).astype(np.int64)
        self.raster_origin = np.array([r[0] for r in rasters], dtype=np.float64)
        self.raster_inv_res = np.array([r[1] for r in rasters], dtype=np.float64)
        self.raster_cell_max = np.array([r[2] for r in rasters], dtype=np.float64)
        self.raster_width = np.array([r[3] for r in rasters], dtype=np.int64)

    def project(self, xy: np.ndarray, heading: np.ndarray | None, map_index: np.ndarray) -> LaneProjection:
        """``smarts.maps.project`` of each point ``xy[i]`` on map ``map_index[i]`` (stacked lanes)."""
        n = np.asarray(xy).reshape(-1, 2).shape[0]
        map_index = np.asarray(map_index, dtype=np.int64).reshape(-1)
        if map_index.shape[0] != n or (n and not (0 <= map_index.min() and map_index.max() < self.num_maps)):
            raise ValueError(f"map_index: expected {n} map numbers from 0 to {self.num_maps - 1}, got {map_index!r}")
        return project_on_grids(self.frozen_grids, xy, heading, map_index)


def _refuse_space(combined: RoadMap) -> None:
    """The combined map has no space of its own: projecting onto it or testing the road surface
    there would mix the maps, so both fail loudly (use a window or ``MapStack.project``)."""

    class _NoSpace:
        def __getattr__(self, name):
            raise TypeError(
                "a stack of maps has no space of its own: project onto one map's window "
                "(MapStack.windows[m]) or with MapStack.project"
            )

        def __bool__(self) -> bool:
            return True

        def __iter__(self):
            return self.__getattr__("__iter__")

    combined.__dict__["_projection_index"] = _NoSpace()
    combined.__dict__["_raster_lookup"] = _NoSpace()


STACKS_KEPT = 8
"""Stacks this process keeps for reuse (see :func:`stack_maps`)."""
_stacks: dict[tuple[int, ...], MapStack] = {}


def stack_maps(maps: Sequence[RoadMap]) -> MapStack:
    """``maps`` in one lane index space (see the module docstring); distinct maps only.

    Maps are read-only once compiled, so the stack of the same map objects is made once per process
    and reused: a benchmark builds one simulation per agent on the same suite, and what the stack's
    windows compute on first use (junction tables, lane exits, routes) then carries over. The key
    is the maps' identities; the stack holds the maps, so an identity is never reused while kept."""
    key = tuple(id(m) for m in maps)
    stack = _stacks.pop(key, None)
    if stack is None:
        stack = MapStack(maps)
    _stacks[key] = stack  # the newest last
    while len(_stacks) > STACKS_KEPT:
        del _stacks[next(iter(_stacks))]
    return stack
