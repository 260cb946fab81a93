"""The built-in traffic provider: departures from the scenario's flows and trips, then the
compiled driver model (``kernels``) over the compiled lane graph, with no external simulator.

Everything a step needs is prepared at construction (routes as slot tables, junction conflict
zones, driver parameters per vehicle type) or at reset (per-row state arrays sized to the vehicle
table). A step is: project other providers' rows onto lanes, sort all road users per lane, one
compiled call that decides and moves every vehicle, then removals and departures (a Python loop
over the few vehicles arriving or departing this step only).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

import smarts.traffic.builtin.kernels as K
from smarts.core.errors import ScenarioError
from smarts.core.provider import ProviderBase
from smarts.core.spec.traffic import (
    DEFAULT_VEHICLE_TYPES,
    DEPART_LANES,
    DEPART_SPEEDS,
    FlowSpec,
    TrafficSpec,
    TripSpec,
    VehicleTypeSpec,
)
from smarts.core.vehicle_table import COLUMN, VEHICLE_DIMENSIONS, Role, VehicleType
from smarts.maps import RoadMap, project
from smarts.traffic.builtin.junctions import junction_table
from smarts.traffic.builtin.routes import NO_WAY, RouteTable
from smarts.traffic.density import density_flows

if TYPE_CHECKING:
    from smarts.core.simulation import Simulation
    from smarts.traffic.signals import SignalState

VEHICLE_BASES = {
    "passenger": VehicleType.PASSENGER,
    "bus": VehicleType.BUS,
    "truck": VehicleType.TRUCK,
    "motorcycle": VehicleType.MOTORCYCLE,
}
TYPE_OF_VEHICLE = {
    VehicleType.PASSENGER: "car",
    VehicleType.BUS: "bus",
    VehicleType.TRUCK: "truck",
    VehicleType.MOTORCYCLE: "motorcycle",
}
"""Driver parameters given to a vehicle adopted from another provider, by its vehicle type."""
MAX_INSERTIONS_PER_STEP = 4  # per flow: departures due together enter over a few steps
FOLLOWER_ROOM = 2.0  # m kept free behind a new vehicle
ON_LANE_TOLERANCE = 1.0  # m beyond the lane edge within which an adopted vehicle counts as on it


@dataclass
class _Source:
    """One flow or trip, compiled: where its vehicles start, what they are, when they leave."""

    id: str
    where: str
    route: int
    vtype: VehicleType
    params: np.ndarray  # float64[NUM_PARAMS]
    length: float
    width: float
    height: float
    speed_factor: float
    speed_dev: float
    depart_lane: str | int
    depart_speed: str | float
    depart_pos: float
    begin: float
    end: float
    period: float = 0.0  # s between departures (rate flows)
    probability: float = 0.0  # per second (probability flows)
    is_trip: bool = False
    # Where vehicles may enter, one entry per lane of the first road (filled by ``_spots``):
    spot_lane: np.ndarray | None = None  # int64 lane
    spot_slot: np.ndarray | None = None  # int64 route slot of the lane
    spot_s: np.ndarray | None = None  # float64 centre arc length
    spot_next: np.ndarray | None = None  # int64 lane after it on the route, -1 if none
    candidates: np.ndarray | None = None  # int64 spots the depart_lane rule chooses among


class BuiltinTrafficProvider(ProviderBase):
    """Vectorised IDM/MOBIL traffic with right of way at junctions and signals."""

    name = "builtin_traffic"

    def __init__(
        self,
        traffic: TrafficSpec,
        road_map: RoadMap,
        dt: float,
        signals: SignalState | None = None,
        compiled: dict | None = None,
    ):
        self.traffic = traffic
        self.map = road_map
        self.dt = float(dt)
        self.signals = signals
        if traffic.pedestrians:
            raise ScenarioError("traffic.pedestrians: the builtin engine has no pedestrians; use engine: sumo")
        self.junctions = junction_table(road_map)
        # ``compiled``: the routes and sources of this traffic on this map compiled for an earlier
        # provider (a batch's episodes of one scenario): sources never change once compiled, and
        # each provider adds its own routes (hand-overs) to a copy of the table.
        key = ("builtin traffic", id(traffic), id(road_map))
        kept = compiled.get(key) if compiled is not None else None
        if kept is not None and kept[0] is traffic and kept[1] is road_map:
            self.routes, self.sources = kept[2].copy(), kept[3]
        else:
            self.routes = RouteTable(road_map)
            self.sources = self._compile_sources(traffic)
            if compiled is not None:
                compiled[key] = (traffic, road_map, self.routes.copy(), self.sources)
        m = road_map
        self.lanes = K.LaneGraph(
            lane_f=np.ascontiguousarray(
                np.stack([m.lane_length, m.lane_width, m.lane_speed_limit, m.lane_internal.astype(float)])
            ),
            lane_lr=np.ascontiguousarray(np.stack([m.lane_left, m.lane_right]).astype(np.int64)),
            pred_off=m.pred_offsets.astype(np.int64),
            pred=m.pred.astype(np.int64),
            point_off=m.lane_point_offsets.astype(np.int64),
            point_s=np.ascontiguousarray(m.point_s, dtype=np.float64),
            points=np.ascontiguousarray(m.points, dtype=np.float64),
            seg_heading=np.ascontiguousarray(m.seg_heading, dtype=np.float64),
        )
        self.frozen_lanes = K.freeze(self.lanes)
        jt = self.junctions
        self.conn_int = np.ascontiguousarray(
            np.stack([jt.conn_from, jt.conn_to, jt.conn_first, jt.conn_major, jt.conn_merge_only]).reshape(5, -1)
        )
        self.no_signals = np.zeros(m.num_lanes, dtype=np.int8)
        self._routes_fields: K.Routes | None = None  # the tables of frozen_routes()
        self._state_fields: K.RowState | None = None  # the arrays of frozen_state()
        self.capacity = 0
        self.step_count = 0
        self.rng = np.random.default_rng(0)

    # ------------------------------------------------------------------ kernel records
    def route_tables(self) -> K.Routes:
        """The route slots and junction tables the kernels read (packing routes added since)."""
        jt = self.junctions
        return K.Routes(
            slot_int=self.routes.slot_int, slot_cost=self.routes.slot_cost, conn_int=self.conn_int,
            conn_len=jt.conn_length, clanes_off=jt.lanes_offsets, clanes=jt.lanes, conn_of_lane=jt.conn_of_lane,
            offset_of_lane=jt.offset_of_lane, foe_off=jt.foe_offsets, foe=jt.foe, foe_kind=jt.foe_kind, zone=jt.zone,
        )  # fmt: skip

    def frozen_routes(self):
        """``route_tables`` frozen, made again when routes were added (a hand-over adds one)."""
        if self._routes_fields is None or self._routes_fields.slot_int is not self.routes.slot_int:
            self._routes_fields = self.route_tables()
            self._frozen_routes = K.freeze(self._routes_fields)
        return self._frozen_routes

    def frozen_state(self):
        """The rows' ``RowState`` frozen, made again when its arrays are replaced (a reset at a
        new capacity, or the batch stage handing the provider views of its blocks)."""
        f = self._state_fields
        if f is None or f.si is not self.si or f.st is not self.st or f.pa is not self.pa or f.mine is not self.mine:
            self._state_fields = K.RowState(si=self.si, st=self.st, pa=self.pa, mine=self.mine)
            self._frozen_state = K.freeze(self._state_fields)
        return self._frozen_state

    # ------------------------------------------------------------------ construction
    def _compile_sources(self, traffic: TrafficSpec) -> list[_Source]:
        """Trips first: when departures compete for a spot, a named vehicle (which an agent may
        be about to take over) gets it."""
        sources = [self._source(trip, f"traffic.trips[{i}]") for i, trip in enumerate(traffic.trips)]
        for i, flow in enumerate(traffic.flows):
            sources.append(self._source(flow, f"traffic.flows[{i}]"))
        for flow in density_flows(traffic, self.map):
            sources.append(self._source(flow, f"traffic.density (flow {flow.id})"))
        # Spots read the packed route arrays: once all routes are in (one pack, not one each).
        for src in sources:
            self._spots(src, self.routes.lanes_of_first_road(src.route))
        return sources

    def _source(self, item: FlowSpec | TripSpec, where: str) -> _Source:
        if not isinstance(item.id, str) or not item.id:
            raise ScenarioError(f"{where}.id: expected a non-empty string, got {item.id!r}")
        route = self._route(item, where)
        vtype = self._vehicle_type(item.vehicle_type, f"{where}.vehicle_type")
        base = VEHICLE_BASES[vtype.base]
        dl, dw, dh, _ = VEHICLE_DIMENSIONS[base]
        lanes = self.routes.lanes_of_first_road(route)
        first_road = self.map.road_ids[self.routes.routes[route][0]]
        _check_depart(item, where, vtype, first_road, self.map.lane_length[lanes])
        src = _Source(
            id=item.id,
            where=where,
            route=route,
            vtype=base,
            params=_behaviour_params(vtype),
            length=float(vtype.length if vtype.length is not None else dl),
            width=float(vtype.width if vtype.width is not None else dw),
            height=float(vtype.height if vtype.height is not None else dh),
            speed_factor=float(vtype.speed_factor),
            speed_dev=float(vtype.speed_dev),
            depart_lane=item.depart_lane,
            depart_speed=item.depart_speed,
            depart_pos=float(item.depart_pos),
            begin=0.0,
            end=math.inf,
        )
        _set_timing(src, item, where)
        return src

    def _spots(self, src: _Source, lanes: list[int]) -> None:
        """Precompute the source's entry spots and which of them its depart_lane rule uses."""
        routes = self.routes
        half = 0.5 * src.length
        src.spot_lane = np.array(lanes, dtype=np.int64)
        src.spot_slot = np.array([routes.slot(src.route, lane) for lane in lanes], dtype=np.int64)
        length = self.map.lane_length[src.spot_lane]
        src.spot_s = np.minimum(np.maximum(src.depart_pos, half), np.maximum(length - 0.1, 0.0))
        nxt = routes.slot_int[K.S_NEXT, src.spot_slot]
        src.spot_next = np.where(nxt >= 0, routes.slot_int[K.S_LANE, np.maximum(nxt, 0)], -1)
        costs = routes.slot_cost[src.spot_slot]
        usable = np.flatnonzero(costs < NO_WAY)
        if usable.size == 0:
            usable = np.arange(len(lanes))
        choice = src.depart_lane
        if isinstance(choice, int):
            src.candidates = np.array([choice])
        elif choice == "first":
            src.candidates = np.array([0])
        elif choice == "best":
            src.candidates = usable[costs[usable] == costs[usable].min()]
        else:  # free, random (one of them drawn per attempt)
            src.candidates = usable
        src.candidates = src.candidates.astype(np.int64)

    def _route(self, item: FlowSpec | TripSpec, where: str) -> int:
        if item.route is not None:
            if item.origin is not None or item.destination is not None:
                raise ScenarioError(f"{where}: give either route or origin and destination")
            if not isinstance(item.route, (list, tuple)) or not all(isinstance(r, str) for r in item.route):
                raise ScenarioError(f"{where}.route: expected a list of road ids, got {item.route!r}")
            return self.routes.add_roads(list(item.route), f"{where}.route")
        for name in ("origin", "destination"):
            if not isinstance(getattr(item, name), str):
                raise ScenarioError(
                    f"{where}.{name}: expected a road id (or give a route), got {getattr(item, name)!r}"
                )
        a = self.routes.road_index(item.origin, f"{where}.origin")
        b = self.routes.road_index(item.destination, f"{where}.destination")
        roads = self.routes.complete([a, b], f"{where}.destination")
        return self.routes.add(roads)

    def _vehicle_type(self, name: str, where: str) -> VehicleTypeSpec:
        if name in self.traffic.vehicle_types:
            vtype = self.traffic.vehicle_types[name]
            field_path = f"traffic.vehicle_types.{name}"
        elif name in DEFAULT_VEHICLE_TYPES:
            return DEFAULT_VEHICLE_TYPES[name]
        else:
            raise ScenarioError(
                f"{where}: unknown vehicle type {name!r}; declared: "
                f"{sorted(self.traffic.vehicle_types)}, built-in: {sorted(DEFAULT_VEHICLE_TYPES)}"
            )
        if vtype.base not in VEHICLE_BASES:
            raise ScenarioError(f"{field_path}.base: expected one of {list(VEHICLE_BASES)}, got {vtype.base!r}")
        for attr in ("max_speed", "accel", "decel", "speed_factor"):
            if not getattr(vtype, attr) > 0:
                raise ScenarioError(f"{field_path}.{attr}: expected > 0, got {getattr(vtype, attr)}")
        for attr in ("tau", "min_gap", "speed_dev", "politeness", "lc_threshold"):
            if not getattr(vtype, attr) >= 0:
                raise ScenarioError(f"{field_path}.{attr}: expected >= 0, got {getattr(vtype, attr)}")
        return vtype

    # ------------------------------------------------------------------ episode
    def reset(self, sim: Simulation) -> None:
        cap = sim.table.capacity
        if cap != self.capacity:
            self.capacity = cap
            # (the batch stage that steps this provider hands it views of its own blocks instead)
            self.si = np.zeros((K.NUM_INT_STATE, cap), dtype=np.int64)
            self.st = np.zeros((K.NUM_FLOAT_STATE, cap))
            self.pa = np.zeros((K.NUM_PARAMS, cap))
            self.mine = np.zeros(cap, dtype=bool)
        self.mine[:] = False
        self.rng = np.random.default_rng(sim.seed)
        self.step_count = 0
        n = len(self.sources)
        self.next_time = np.array([s.begin for s in self.sources], dtype=np.float64)
        for k, src in enumerate(self.sources):
            if src.probability > 0:
                self.next_time[k] = src.begin + (self._geometric(src) - 1) * self.dt
        self.pending = np.zeros(n, dtype=np.int64)
        self.count = np.zeros(n, dtype=np.int64)
        self._depart(sim, sim.time)

    def _geometric(self, src: _Source) -> int:
        """Steps until the next departure of a probability flow (at least 1)."""
        return int(self.rng.geometric(min(src.probability * self.dt, 1.0)))

    def close(self) -> None:
        pass

    # ------------------------------------------------------------------ step
    @property
    def batch_stage(self):
        """Every built-in traffic provider of a simulation is stepped by one ``BuiltinTrafficStage``
        (``smarts.traffic.builtin.stage``), whatever the number of episodes."""
        from smarts.traffic.builtin.stage import BuiltinTrafficStage

        return BuiltinTrafficStage

    def _others(self, table):
        """Rows of other providers with their current lane coordinates (projected now: agents
        moved earlier in this step)."""
        rows = np.flatnonzero(table.alive & ~self.mine)
        if rows.size == 0:
            empty_f = np.zeros(0)
            return rows, np.zeros(0, dtype=np.int64), empty_f, empty_f, empty_f
        proj = project(self.map, table.data[_XY][:, rows].T, table.heading[rows])
        return (rows, proj.lane.astype(np.int64), proj.s, proj.t, table.heading[rows] - proj.lane_heading)

    # ------------------------------------------------------------------ departures
    def _depart(self, sim: Simulation, time: float, foreign=None, f_lane=None, f_s=None) -> None:
        due = np.flatnonzero(self.next_time <= time + 1e-9)
        for k in due.tolist():
            src = self.sources[k]
            while self.next_time[k] <= time + 1e-9:
                self.pending[k] += 1
                if src.is_trip:
                    self.next_time[k] = math.inf
                elif src.period > 0:
                    self.next_time[k] += src.period
                else:
                    self.next_time[k] += self._geometric(src) * self.dt
                if self.next_time[k] >= src.end:
                    self.next_time[k] = math.inf
        waiting = np.flatnonzero(self.pending > 0)
        if waiting.size == 0:
            return
        if foreign is None:
            foreign, f_lane, f_s, _, _ = self._others(sim.table)
        own = np.flatnonzero(self.mine)
        for k in waiting.tolist():
            for _ in range(MAX_INSERTIONS_PER_STEP):
                row = self._insert(sim, k, own, foreign, f_lane, f_s) if self.pending[k] else -1
                if row < 0:
                    break
                own = np.append(own, row)
                self.pending[k] -= 1
                self.count[k] += 1

    def _insert(self, sim: Simulation, k: int, own, foreign, f_lane, f_s) -> int:
        """Try to put source ``k``'s next vehicle on the road: its row, or -1 when its spot is
        taken (it tries again next step)."""
        src = self.sources[k]
        table = sim.table
        spots = src.candidates
        if src.depart_lane == "random" and len(spots) > 1:
            spots = spots[int(self.rng.integers(len(spots)))][None]
        room = K.clearance(
            self.frozen_lanes, self.frozen_routes(), self.frozen_state(), table.data, own, foreign, f_lane, f_s,
            src.spot_lane[spots], src.spot_s[spots], src.spot_next[spots], 0.5 * src.length,
        )  # fmt: skip
        pick = int(np.argmax(np.minimum(room[0], room[2])))  # the spot with the most room
        ahead, v_ahead, behind, v_behind = room[:, pick]
        i = int(spots[pick])
        s0, tau = src.params[K.MIN_GAP], src.params[K.TAU]
        if ahead < s0:
            return -1
        if src.speed_dev > 0:
            factor = float(self.rng.normal(src.speed_factor, src.speed_dev))
        else:
            factor = src.speed_factor
        factor = max(min(factor, src.speed_factor + 2 * src.speed_dev), src.speed_factor - 2 * src.speed_dev, 0.1)
        lane = int(src.spot_lane[i])
        v0 = min(src.params[K.MAX_SPEED], float(self.map.lane_speed_limit[lane]) * factor)
        want = src.depart_speed
        if want in ("desired", "max"):
            speed = v0
        elif want == "random":
            speed = float(self.rng.uniform(0.0, v0))
        else:
            speed = float(want)
        accel, decel = src.params[K.ACCEL], src.params[K.DECEL]
        if ahead < K.INF * 0.5:  # slow down until following the vehicle ahead is comfortable
            while speed > 0.0 and K.idm(speed, v0, ahead, v_ahead, accel, decel, tau, s0) < -decel:
                speed = speed * 0.8 if speed > 1.0 else 0.0
        if behind < K.INF * 0.5 and (
            behind < FOLLOWER_ROOM or K.idm(v_behind, max(v_behind, 1.0), behind, speed, 2.6, 4.5, 1.0, 2.5) < -4.5
        ):
            return -1  # the vehicle behind could not brake for it comfortably
        vid = src.id if src.is_trip else f"{src.id}.{int(self.count[k])}"
        if vid in table.row_of:
            raise ScenarioError(f"{src.where}.id: vehicle id {vid!r} is already in use")
        row = table.add(
            vid,
            owner=self.provider_id,
            role=Role.TRAFFIC,
            x=0.0,
            y=0.0,
            heading=0.0,
            speed=speed,
            vtype=src.vtype,
            length=src.length,
            width=src.width,
            height=src.height,
        )
        self._adopt_row(row, int(src.spot_slot[i]), float(src.spot_s[i]), 0.0, factor, src.params)
        K.place_vehicle(self.frozen_lanes, self.frozen_routes(), self.frozen_state(), table.data, row)
        return row

    def _adopt_row(self, row: int, slot: int, s: float, lat: float, factor: float, params: np.ndarray) -> None:
        self.si[:, row] = (slot, -1, -1, -1)
        moving = abs(lat) > 1e-3
        self.st[:, row] = 0.0
        self.st[K.S, row] = s
        self.st[K.LAT, row] = lat
        self.st[K.LAT0, row] = lat
        self.st[K.LC_PROG, row] = 0.0 if moving else 1.0
        self.st[K.COOL, row] = K.LC_DURATION if moving else 0.0
        self.st[K.FACTOR, row] = factor
        self.pa[:, row] = params
        self.mine[row] = True

    # ------------------------------------------------------------------ hand-over
    def can_accept(self, sim: Simulation, rows: np.ndarray) -> np.ndarray:
        """Any motor vehicle on a lane: it gets a route from there to a way out of the map
        (pedestrians and cyclists are not driven by the car model)."""
        rows = np.asarray(rows, dtype=np.int64)
        t = sim.table
        if rows.size == 0:
            return np.zeros(0, dtype=bool)
        proj = project(self.map, t.data[_XY][:, rows].T, t.heading[rows])
        lane = proj.lane
        ok = (lane >= 0) & ~np.isin(t.vtype[rows], _NOT_DRIVEN) & t.alive[rows]
        width = np.where(lane >= 0, self.map.lane_width[np.maximum(lane, 0)], 0.0)
        return ok & (proj.distance <= 0.5 * width + ON_LANE_TOLERANCE)

    def accept(self, sim: Simulation, rows: np.ndarray) -> None:
        """Drive rows handed over by another provider on from their current pose and speed."""
        rows = np.asarray(rows, dtype=np.int64)
        if rows.size == 0:
            return
        bad = rows[~self.can_accept(sim, rows)]
        if bad.size:
            raise ValueError(
                f"builtin traffic cannot take vehicles {[sim.table.ids[r] for r in bad]}: they are not on a lane"
            )
        t = sim.table
        proj = project(self.map, t.data[_XY][:, rows].T, t.heading[rows])
        for i, row in enumerate(rows.tolist()):
            lane = int(proj.lane[i])
            route = self.routes.add_from_lane(lane)
            slot = self.routes.slot(route, lane)
            s = float(np.clip(proj.s[i], 0.0, self.map.lane_length[lane]))
            vtype = DEFAULT_VEHICLE_TYPES[TYPE_OF_VEHICLE.get(VehicleType(int(t.vtype[row])), "car")]
            params = np.array(
                [
                    vtype.accel,
                    vtype.decel,
                    max(vtype.emergency_decel, vtype.decel),
                    vtype.tau,
                    vtype.min_gap,
                    vtype.max_speed,
                    vtype.politeness,
                    vtype.lc_threshold,
                    vtype.lc_keep_right,
                ],
                dtype=np.float64,
            )
            params[K.MAX_SPEED] = max(params[K.MAX_SPEED], float(t.speed[row]))
            self._adopt_row(row, slot, s, float(proj.t[i]), 1.0, params)

    def release(self, sim: Simulation, rows: np.ndarray) -> None:
        """Forget rows handed to another provider (or removed)."""
        rows = np.asarray(rows, dtype=np.int64)
        if rows.size and self.capacity:
            self.mine[rows] = False


_XY = [COLUMN["x"], COLUMN["y"]]
_NOT_DRIVEN = np.array([int(VehicleType.PEDESTRIAN), int(VehicleType.BICYCLE)], dtype=np.int8)


def _check_depart(
    item: FlowSpec | TripSpec, where: str, vtype: VehicleTypeSpec, first_road: str, lane_lengths: np.ndarray
) -> None:
    """The depart lane, speed and position fit the first road's lanes and the vehicle type."""
    lane_choice = item.depart_lane
    if isinstance(lane_choice, bool) or not isinstance(lane_choice, (int, str)):
        raise ScenarioError(
            f"{where}.depart_lane: expected a lane index or one of {list(DEPART_LANES)}, got {lane_choice!r}"
        )
    if isinstance(lane_choice, int) and not 0 <= lane_choice < len(lane_lengths):
        raise ScenarioError(
            f"{where}.depart_lane: road {first_road!r} has {len(lane_lengths)} lane(s) "
            f"(0..{len(lane_lengths) - 1}), got {lane_choice}"
        )
    if isinstance(lane_choice, str) and lane_choice not in DEPART_LANES:
        raise ScenarioError(
            f"{where}.depart_lane: expected a lane index or one of {list(DEPART_LANES)}, got {lane_choice!r}"
        )
    speed = item.depart_speed
    if isinstance(speed, str):
        if speed not in DEPART_SPEEDS:
            raise ScenarioError(f"{where}.depart_speed: expected m/s or one of {list(DEPART_SPEEDS)}, got {speed!r}")
    elif isinstance(speed, bool) or not isinstance(speed, (int, float)) or not (0.0 <= speed <= vtype.max_speed):
        raise ScenarioError(
            f"{where}.depart_speed: expected 0..{vtype.max_speed} m/s (the vehicle type's "
            f"max_speed) or one of {list(DEPART_SPEEDS)}, got {speed!r}"
        )
    shortest = float(lane_lengths.min())
    if not 0.0 <= float(item.depart_pos) <= shortest:
        raise ScenarioError(f"{where}.depart_pos: road {first_road!r} is {shortest:.1f} m long, got {item.depart_pos}")


def _behaviour_params(vtype: VehicleTypeSpec) -> np.ndarray:
    """The car-following and lane-change parameters of a vehicle type, in the kernels' column order."""
    return np.array(
        [
            vtype.accel,
            vtype.decel,
            max(vtype.emergency_decel, vtype.decel),
            vtype.tau,
            vtype.min_gap,
            vtype.max_speed,
            vtype.politeness,
            vtype.lc_threshold,
            vtype.lc_keep_right,
        ],
        dtype=np.float64,
    )


def _set_timing(src: _Source, item: FlowSpec | TripSpec, where: str) -> None:
    """A trip departs once at its depart time; a flow emits at a rate or a probability from begin to end."""
    if isinstance(item, TripSpec):
        if not item.depart >= 0.0:
            raise ScenarioError(f"{where}.depart: expected a time >= 0 s, got {item.depart}")
        src.begin, src.end, src.is_trip = float(item.depart), float(item.depart), True
        return
    has_rate, has_prob = item.rate is not None, item.probability is not None
    if has_rate == has_prob:
        raise ScenarioError(f"{where}: give exactly one of rate (veh/h) or probability (per s)")
    if has_rate and not item.rate > 0:
        raise ScenarioError(f"{where}.rate: expected vehicles per hour > 0, got {item.rate}")
    if has_prob and not 0.0 < item.probability <= 1.0:
        raise ScenarioError(f"{where}.probability: expected a probability per second in (0, 1], got {item.probability}")
    if not 0.0 <= item.begin < item.end:
        raise ScenarioError(f"{where}.end: expected 0 <= begin < end, got begin {item.begin}, end {item.end}")
    src.begin, src.end = float(item.begin), float(item.end)
    if has_rate:
        src.period = 3600.0 / float(item.rate)
    else:
        src.probability = float(item.probability)
