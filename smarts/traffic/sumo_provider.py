"""SUMO traffic in-process through libsumo: flows, trips, pedestrians and signals from SUMO.

Co-simulation, each step:

1. Mirror: every agent vehicle (rows of role AGENT or SOCIAL_AGENT owned by another provider, and
   traffic vehicles this provider released to another owner) has a twin in SUMO that is placed at
   the agent's pose with ``moveToXY`` and given its speed, with SUMO's safety checks and lane
   changes switched off. SUMO's drivers see the twin and react to it (follow, brake, yield).
   A new twin is put on its lane at once (``moveTo``), before SUMO's next insertion, so SUMO
   never inserts a vehicle onto or right behind an agent at speed (at the start in particular).
2. ``simulation.step()``.
3. Read: departed vehicles and persons get rows, arrived ones lose theirs; the poses of all others
   are read and written into the table by one compiled kernel.
4. Signals: SUMO's signal states go into the ``SignalState`` (only when they changed).

Reading uses plain libsumo getters mapped over a cached id list rather than subscriptions:
measured on the 6-lane highway with ~40 vehicles, a subscription costs SUMO about 1 us per
vehicle inside ``simulation.step`` and its results another ~1 us to turn into Python dicts, while
three getters cost ~1.5 us per vehicle in all (measured again with ~46 vehicles: per-vehicle
subscriptions read through one ``getAllSubscriptionResults`` per step, or one context
subscription, cost SUMO ~90 us more per step and ~40 us more to read than the getters). Departures
and arrivals are read with the simulation's getters too: a subscription to them made every
``simulation.step`` ~10 us dearer. Acceleration is the speed difference over the step,
which is exactly SUMO's own value under its Euler update.

Conventions converted here: SUMO positions a vehicle by its front bumper and measures angles in
degrees clockwise from north; the table holds box centres and radians counter-clockwise from east.
Offsets along a lane are metres along its shape here and SUMO's lane ``length`` there
(``RoadMap.to_sumo_pos``); poses are exchanged as x, y, which need no conversion.
SUMO's clock runs one step ahead of the simulation's: ``reset`` steps SUMO once so vehicles that
depart at time 0 are already on the road in the first observation.

Hand-over: ``accept`` turns an agent's twin (or a new SUMO vehicle placed at the row's pose) into
a normal SUMO vehicle heading for the end of the agent's route, else for a random reachable exit;
``release`` keeps a traffic vehicle in SUMO as a twin moved by its new owner.

libsumo runs one simulation per process: this provider starts it on its first reset and reloads it
(``simulation.load``) on every later reset; a second open provider in the same process is an
error. Parallel environments therefore run in separate processes.
"""

from __future__ import annotations

import contextlib
import gc
import hashlib
import io
import math
import os
import shutil
import tempfile
import warnings
import weakref
import xml.etree.ElementTree as ET
from itertools import chain
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from smarts.compiled import njit
from smarts.core.errors import ScenarioError
from smarts.core.provider import ProviderBase
from smarts.core.spec.traffic import TrafficSpec
from smarts.core.vehicle_table import COLUMN, Role, VehicleType
from smarts.maps import RoadMap, project
from smarts.traffic.density import exit_roads
from smarts.traffic.signals import SignalState
from smarts.traffic.sumo_routes import (
    AGENT_VTYPE,
    VehicleTypeInfo,
    all_flows,
    used_vehicle_types,
    vehicle_type_info,
    write_route_file,
)

if TYPE_CHECKING:
    from smarts.core.simulation import Simulation

LANE_CHANGE_DURATION = 2.0
"""Seconds a SUMO lane change takes. Continuous lane changes move vehicles sideways smoothly
(no 3 m jump in one step, which would read as a huge lateral acceleration); the sublane model
would cost several times more per vehicle."""
DEFAULT_SPEED_MODE = 31
"""SUMO's default speed mode: all safety checks on."""
DEFAULT_LANE_CHANGE_MODE = 1621
"""SUMO's default lane-change mode (0b011001010101)."""
PEDESTRIAN_PREFIX = "ped:"
"""Row ids of SUMO persons are ``ped:<person id>`` so they never clash with vehicle ids."""
PEDESTRIAN_BOX = (0.5, 0.5, 1.7)
"""Length, width, height of a pedestrian's row."""
TWIN_MATCH_RADIUS = 25.0
"""Metres around an agent that SUMO searches for a lane to put its twin on. SUMO's default of
100 m costs ~3x more per ``moveToXY``; a twin farther than this from every lane is placed off the
network, where SUMO's traffic ignores it, until it comes back."""

_OPEN_PROVIDER: weakref.ref | None = None  # the provider that holds this process's libsumo


def _libsumo():
    """Import libsumo with the eclipse-sumo package's data folder as SUMO_HOME."""
    import sumo

    os.environ.setdefault("SUMO_HOME", sumo.SUMO_HOME)
    import libsumo

    return libsumo


class _Readings:
    """SUMO ids read every step (in a stable order) and their table rows."""

    def __init__(self, prefix: str):
        self.prefix = prefix
        self.ids: dict[str, None] = {}  # insertion-ordered set
        self.order: list[str] = []
        self.rows = np.zeros(0, dtype=np.int64)
        self.dirty = False

    def add(self, sumo_id: str) -> None:
        self.ids[sumo_id] = None
        self.dirty = True

    def discard(self, sumo_id: str) -> None:
        if self.ids.pop(sumo_id, 0) is None:
            self.dirty = True


class SumoTrafficProvider(ProviderBase):
    """Traffic (vehicles, pedestrians, signal states) simulated by SUMO in this process."""

    name = "sumo"

    def __init__(
        self,
        traffic: TrafficSpec,
        road_map: RoadMap,
        net_file: Path,
        dt: float,
        signals: SignalState | None = None,
    ):
        global _OPEN_PROVIDER
        self.traffic = traffic
        self.road_map = road_map
        self.net_file = Path(net_file)
        self.dt = float(dt)
        self.signals = signals
        _check_net_file(self.net_file, road_map)
        work_dir = Path(tempfile.mkdtemp(prefix="smarts-sumo-"))
        try:
            self.route_file = write_route_file(traffic, road_map, work_dir, 0, self.net_file)
            other = _OPEN_PROVIDER() if _OPEN_PROVIDER is not None else None
            if other is not None and not other.closed:
                # An env nobody references any more may only wait for the cycle collector.
                del other
                gc.collect()
                other = _OPEN_PROVIDER() if _OPEN_PROVIDER is not None else None
            if other is not None and not other.closed:
                raise RuntimeError(
                    "another SumoTrafficProvider is open in this process; libsumo runs one SUMO "
                    "simulation per process, so close the other one first (or run parallel "
                    "environments in separate processes)"
                )
        except BaseException:
            shutil.rmtree(work_dir, ignore_errors=True)
            raise
        flows = all_flows(traffic, road_map)
        self.type_info: dict[str, VehicleTypeInfo] = {
            name: vehicle_type_info(spec) for name, spec in used_vehicle_types(traffic, flows).items()
        }
        self.has_pedestrians = bool(traffic.pedestrians)
        self.closed = False
        self._started = [False]  # shared with the finalizer, which must not hold ``self``
        _OPEN_PROVIDER = weakref.ref(self)
        self._finalizer = weakref.finalize(self, _shut_down, work_dir, self._started)
        self._exit_roads = sorted(exit_roads(road_map))
        self._ls = None
        self._reset_episode_state()

    # ------------------------------------------------------------------ episode
    def _reset_episode_state(self) -> None:
        self._vehicles = _Readings("")  # traffic vehicles we own
        self._persons = _Readings(PEDESTRIAN_PREFIX)
        self._twins: set[str] = set()  # SUMO ids of vehicles we move (agent twins)
        self._released: set[str] = set()  # released traffic: twins although their role is TRAFFIC
        self._routes: set[str] = set()  # one-edge route ids created this episode
        self._tls_ids: list[str] = []
        self._tls_last: list[str] = []
        self._warned_full = False

    def sumo_args(self, seed: int) -> list[str]:
        """SUMO's options for an episode with this seed."""
        # fmt: off
        return [
            "-n", str(self.net_file),
            "-r", str(self.route_file),
            "--step-length", repr(self.dt),
            "--begin", "0",
            "--seed", str(int(seed) % 2_147_483_647),
            "--no-step-log", "true",
            "--no-warnings", "true",
            "--time-to-teleport", "-1",
            "--collision.action", "none",  # collisions are detected by the simulation's events
            "--lanechange.duration", repr(LANE_CHANGE_DURATION),
            "--xml-validation", "never",
        ]
        # fmt: on

    def reset(self, sim: Simulation) -> None:
        if self.closed:
            raise RuntimeError("this SumoTrafficProvider was closed")
        if abs(sim.dt - self.dt) > 1e-9:
            raise ValueError(f"SUMO runs with step {self.dt} s but the simulation steps {sim.dt} s")
        ls = self._ls = _libsumo()
        self._reset_episode_state()
        self._rng = np.random.default_rng([int(sim.seed), 0x5A30])
        args = self.sumo_args(sim.seed)
        try:
            if self._started[0]:
                ls.simulation.load(args)
            else:
                if ls.simulation.isLoaded():
                    raise RuntimeError(
                        "libsumo already runs a simulation in this process that this provider "
                        "did not start; libsumo holds one simulation per process"
                    )
                ls.simulation.start(["sumo", *args])
                self._started[0] = True
            if self.signals is not None:
                self._tls_ids = list(ls.trafficlight.getIDList())
                self._tls_last = [""] * len(self._tls_ids)
            self._mirror(sim)
            _C.simulation_step(0.0)
        except (ls.TraCIException, ls.FatalTraCIError) as err:
            self._abandon_sumo()
            raise ScenarioError(f"SUMO could not start the scenario's traffic: {err}") from None
        self._read(sim)

    def _abandon_sumo(self) -> None:
        """Close a SUMO that failed to start, so a later reset (or provider) starts afresh."""
        self._started[0] = False
        with contextlib.suppress(self._ls.TraCIException, self._ls.FatalTraCIError):
            self._ls.simulation.close()

    # ------------------------------------------------------------------ step
    def step(self, sim: Simulation, dt: float) -> None:
        self._mirror(sim)
        _C.simulation_step(0.0)
        self._read(sim)

    def _mirror(self, sim: Simulation) -> None:
        """Move each agent's SUMO twin to the agent's pose (add twins for new agents, drop
        twins whose vehicle left the table)."""
        t = sim.table
        rows = _twin_rows(t.alive, t.owner, t.role, self.provider_id)
        ids = [t.ids[r] for r in rows]
        if self._released:
            extra = [t.row_of.get(v) for v in self._released]
            extra = [r for r in extra if r is not None and t.owner[r] != self.provider_id]
            self._released = {t.ids[r] for r in extra}
            extra = [r for r in extra if t.ids[r] not in ids]
            if extra:
                rows = np.concatenate([rows, np.array(extra, dtype=np.int64)])
                ids += [t.ids[r] for r in extra]
        if len(self._twins) != len(ids) or not self._twins.issuperset(ids):
            for vid in self._twins.difference(ids):
                self._drop_twin(vid)
            for vid, row in zip(ids, rows.tolist()):
                if vid not in self._twins:
                    self._add_twin(sim, vid, row)
        if not ids:
            return
        pose = _twin_poses(t.data, rows)  # front-bumper x, y, SUMO angle, speed
        move, set_speed = _C.vehicle_moveToXY, _C.vehicle_setSpeed
        for vid, (x, y, angle, speed) in zip(ids, pose.tolist()):
            try:
                move(vid, "", -1, x, y, angle, 2, TWIN_MATCH_RADIUS)
                set_speed(vid, speed)
            except self._ls.TraCIException:
                self._drop_twin(vid)  # SUMO lost it (e.g. removed it): re-added next step

    def _add_twin(self, sim: Simulation, vid: str, row: int) -> None:
        ls, t = self._ls, sim.table
        try:
            ls.vehicle.add(vid, self._edge_route(sim, row), typeID=AGENT_VTYPE)
        except ls.TraCIException:
            pass  # SUMO still has a vehicle of this id: take it over
        ls.vehicle.setLength(vid, float(t.length[row]))
        ls.vehicle.setWidth(vid, float(t.width[row]))
        ls.vehicle.setHeight(vid, float(t.height[row]))
        ls.vehicle.setSpeedMode(vid, 0)
        ls.vehicle.setLaneChangeMode(vid, 0)
        self._twins.add(vid)
        self._place_twin(sim, vid, row)

    def _place_twin(self, sim: Simulation, vid: str, row: int) -> None:
        """Put a new twin on its lane at once, so SUMO's insertion checks see it before they
        insert any vehicle. A vehicle added through libsumo waits for the next step's insertion
        phase, which may insert flows first: a car could appear right behind (or on) an agent at
        full speed. A twin off the normal lanes (inside a junction, off the road) is left to the
        step's ``moveToXY``."""
        t, rm = sim.table, self.road_map
        # The table's lane columns are those of the last step (or unset for a new vehicle).
        proj = project(rm, np.array([[t.x[row], t.y[row]]]), np.array([t.heading[row]]))
        lane = int(proj.lane[0])
        if lane < 0 or rm.lane_internal[lane] or proj.distance[0] > 0.5 * rm.lane_width[lane]:
            return
        lane_id = rm.lane_ids[lane]
        front = float(proj.s[0]) + 0.5 * float(t.length[row])
        try:
            self._ls.vehicle.moveTo(vid, lane_id, rm.to_sumo_pos(lane, front))
        except self._ls.TraCIException:
            pass  # SUMO cannot put it there: the step's moveToXY places it

    def _drop_twin(self, vid: str) -> None:
        self._twins.discard(vid)
        try:
            self._ls.vehicle.remove(vid)
        except self._ls.TraCIException:
            pass  # SUMO already dropped it

    def _edge_route(self, sim: Simulation, row: int) -> str:
        """A one-edge SUMO route on the normal road under (or just past) the row."""
        rm, t = self.road_map, sim.table
        lane = int(t.lane[row])
        if lane < 0:
            proj = project(rm, np.array([[t.x[row], t.y[row]]]), np.array([t.heading[row]]))
            lane = int(proj.lane[0])
        seen = set()
        while lane >= 0 and rm.lane_internal[lane] and lane not in seen:
            seen.add(lane)
            nxt = rm.successors(lane)
            lane = int(nxt[0]) if len(nxt) else -1
        if lane < 0:
            lane = int(np.flatnonzero(~rm.lane_internal)[0])
        edge = rm.road_ids[int(rm.lane_road[lane])]
        route_id = f"smarts.edge.{edge}"
        if route_id not in self._routes:
            self._ls.route.add(route_id, [edge])
            self._routes.add(route_id)
        return route_id

    def _read(self, sim: Simulation) -> None:
        t = sim.table
        arrived = _C.simulation_getArrivedIDList()
        if arrived:
            self._arrive(t, arrived, self._vehicles)
        departed = _C.simulation_getDepartedIDList()
        if departed:
            self._depart_vehicles(sim, departed)
        self._read_poses(t, self._vehicles, _C.vehicle_getPosition, _C.vehicle_getAngle, _C.vehicle_getSpeed, 0.5)
        if self.has_pedestrians:
            arrived = _C.simulation_getArrivedPersonIDList()
            if arrived:
                self._arrive(t, arrived, self._persons)
            departed = _C.simulation_getDepartedPersonIDList()
            if departed:
                self._depart_persons(sim, departed)
            self._read_poses(t, self._persons, _C.person_getPosition, _C.person_getAngle, _C.person_getSpeed, 0.0)
        if self._tls_ids:
            states = list(map(_C.trafficlight_getRedYellowGreenState, self._tls_ids))
            if states != self._tls_last:
                changed = {tls: s for tls, s, old in zip(self._tls_ids, states, self._tls_last) if s != old}
                self._tls_last = states
                self.signals.set_states(changed)

    def _read_poses(self, t, readings: _Readings, get_pos, get_angle, get_speed, front) -> None:
        if readings.dirty:
            self._refresh_rows(t, readings)
        ids = readings.order
        n = len(ids)
        if n == 0:
            return
        pos = np.fromiter(chain.from_iterable(map(get_pos, ids)), np.float64, 2 * n)
        angle = np.fromiter(map(get_angle, ids), np.float64, n)
        speed = np.fromiter(map(get_speed, ids), np.float64, n)
        _write_states(t.data, readings.rows, pos, angle, speed, self.dt, front)

    def _refresh_rows(self, t, readings: _Readings) -> None:
        """Rows of the ids read each step. Ids whose row vanished or changed owner without a
        ``release`` are dropped from SUMO / turned into twins."""
        prefix = readings.prefix
        rows = [t.row_of.get(prefix + k, -1) for k in readings.ids]
        lost = [k for k, r in zip(readings.ids, rows) if r < 0 or t.owner[r] != self.provider_id]
        for k in lost:
            readings.ids.pop(k)
            row = t.row_of.get(prefix + k)
            domain = self._ls.person if prefix else self._ls.vehicle
            if row is None or prefix:
                try:
                    domain.remove(k)
                except self._ls.TraCIException:
                    pass
            else:
                self._make_twin(k)
        if lost:
            rows = [t.row_of[prefix + k] for k in readings.ids]
        readings.order = list(readings.ids)
        readings.rows = np.array(rows, dtype=np.int64)
        readings.dirty = False

    def _arrive(self, table, ids, readings: _Readings) -> None:
        rows = []
        for sumo_id in ids:
            if not readings.prefix and sumo_id in self._twins:
                self._twins.discard(sumo_id)  # a twin's route ended: re-added next step
                continue
            readings.discard(sumo_id)
            row = table.row_of.get(readings.prefix + sumo_id)
            if row is not None and table.owner[row] == self.provider_id:
                rows.append(row)
        if rows:
            table.remove(rows)

    def _depart_vehicles(self, sim: Simulation, ids) -> None:
        t = sim.table
        for vid in ids:
            if vid in self._twins:
                continue
            row = t.row_of.get(vid)
            if row is not None:  # handed to us before SUMO inserted it (and maybe away again)
                if t.owner[row] == self.provider_id:
                    self._vehicles.add(vid)
                else:
                    self._make_twin(vid)
                continue
            info = self.type_info.get(_C.vehicle_getTypeID(vid))
            if info is None:  # a type made on the fly: ask SUMO
                info = VehicleTypeInfo(
                    VehicleType.PASSENGER,
                    _C.vehicle_getLength(vid),
                    _C.vehicle_getWidth(vid),
                    _C.vehicle_getHeight(vid),
                )
            pose = (
                *_C.vehicle_getPosition(vid),
                _C.vehicle_getAngle(vid),
                _C.vehicle_getSpeed(vid),
            )
            if self._add_row(sim, vid, Role.TRAFFIC, info, pose, 0.5):
                self._vehicles.add(vid)
            else:
                self._ls.vehicle.remove(vid)

    def _depart_persons(self, sim: Simulation, ids) -> None:
        info = VehicleTypeInfo(VehicleType.PEDESTRIAN, *PEDESTRIAN_BOX)
        for pid in ids:
            pose = (*_C.person_getPosition(pid), _C.person_getAngle(pid), _C.person_getSpeed(pid))
            if self._add_row(sim, PEDESTRIAN_PREFIX + pid, Role.PEDESTRIAN, info, pose, 0.0):
                self._persons.add(pid)
            else:
                self._ls.person.remove(pid)

    def _add_row(self, sim, row_id: str, role: Role, info: VehicleTypeInfo, pose, front) -> bool:
        """Add a row for a departure; False when the table is full (the departure is dropped)."""
        t = sim.table
        fx, fy, angle, speed = pose
        heading = _heading_of_angle(angle)
        back = front * info.length
        try:
            t.add(
                row_id,
                owner=self.provider_id,
                role=role,
                x=fx - back * math.cos(heading),
                y=fy - back * math.sin(heading),
                heading=heading,
                speed=speed,
                vtype=info.vtype,
                length=info.length,
                width=info.width,
                height=info.height,
            )
        except RuntimeError:
            if not self._warned_full:
                self._warned_full = True
                warnings.warn(
                    f"vehicle table full (capacity {t.capacity}): SUMO traffic that does not fit "
                    "is dropped; raise the scenario's 'vehicle_capacity'",
                    stacklevel=2,
                )
            return False
        return True

    # ------------------------------------------------------------------ hand-over
    def can_accept(self, sim: Simulation, rows: np.ndarray) -> np.ndarray:
        """Vehicles on a lane (within its width) that SUMO can drive: not pedestrians, not
        already ours; inside a junction only if SUMO already has their twin."""
        rows = np.asarray(rows, dtype=np.int64)
        t, rm = sim.table, self.road_map
        lane = t.lane[rows]
        ok = t.alive[rows] & (lane >= 0) & (t.owner[rows] != self.provider_id)
        ok &= (t.vtype[rows] != int(VehicleType.PEDESTRIAN)) & (t.vtype[rows] != int(VehicleType.BICYCLE))
        safe_lane = np.where(lane >= 0, lane, 0)
        ok &= t.lane_distance[rows] <= 0.5 * rm.lane_width[safe_lane]
        internal = rm.lane_internal[safe_lane]
        if internal.any():
            ok &= ~internal | np.array([t.ids[r] in self._twins for r in rows], dtype=bool)
        return ok & self._started[0] & (not self.closed)

    def accept(self, sim: Simulation, rows: np.ndarray) -> None:
        """SUMO drives these rows from now on, towards the agent's route end or a random exit."""
        ls, t = self._ls, sim.table
        for row in np.asarray(rows, dtype=np.int64).tolist():
            vid = t.ids[row]
            if vid in self._twins:
                self._twins.discard(vid)
                self._released.discard(vid)
                self._vehicles.add(vid)
            else:  # a vehicle SUMO has never seen: insert it at the row's pose
                x, y, angle, speed = _twin_poses(t.data, np.array([row]))[0].tolist()
                ls.vehicle.add(vid, self._edge_route(sim, row), typeID=AGENT_VTYPE, departSpeed=f"{speed:.3f}")
                ls.vehicle.setLength(vid, float(t.length[row]))
                ls.vehicle.setWidth(vid, float(t.width[row]))
                ls.vehicle.moveToXY(vid, "", -1, x, y, angle, 2, TWIN_MATCH_RADIUS)
                # read from its departure on (``_depart_vehicles``)
            ls.vehicle.setSpeedMode(vid, DEFAULT_SPEED_MODE)
            ls.vehicle.setLaneChangeMode(vid, DEFAULT_LANE_CHANGE_MODE)
            ls.vehicle.setSpeed(vid, -1.0)  # SUMO's car following takes over
            self._give_destination(sim, vid)

    def _give_destination(self, sim: Simulation, vid: str) -> None:
        """Route to the end of the agent's route when that is an exit of the map (so the vehicle
        leaves the map instead of vanishing mid-road), else to a random reachable exit, else to
        the route's end."""
        rm = self.road_map
        route_end = []
        row = sim.table.row_of[vid]
        for agent in np.flatnonzero(sim.agent_row == row).tolist():  # the agent that drove it
            lanes = sim.missions[agent].route
            normal = lanes[~rm.lane_internal[lanes]]
            if len(normal):
                route_end.append(int(rm.lane_road[normal[-1]]))
        exits = [e for e in route_end if e in self._exit_roads]
        exits += [self._exit_roads[i] for i in self._rng.permutation(len(self._exit_roads))]
        for road in [rm.road_ids[r] for r in exits + route_end]:
            try:
                self._ls.vehicle.changeTarget(vid, road)
                return
            except self._ls.TraCIException:
                continue  # not reachable from where the vehicle is

    def release(self, sim: Simulation, rows: np.ndarray) -> None:
        """Rows leaving SUMO's control stay in SUMO as twins moved by their new owner
        (pedestrians, which SUMO cannot move that way, leave SUMO)."""
        if not self._started[0] or self.closed:
            return
        t = sim.table
        for row in np.asarray(rows, dtype=np.int64).tolist():
            vid = t.ids[row]
            if vid is None:
                continue
            if t.vtype[row] == int(VehicleType.PEDESTRIAN):
                pid = vid[len(PEDESTRIAN_PREFIX) :]
                self._persons.discard(pid)
                try:
                    self._ls.person.remove(pid)
                except self._ls.TraCIException:
                    pass
            elif vid in self._vehicles.ids:
                self._vehicles.discard(vid)
                self._make_twin(vid)

    def _make_twin(self, vid: str) -> None:
        self._ls.vehicle.setSpeedMode(vid, 0)
        self._ls.vehicle.setLaneChangeMode(vid, 0)
        self._twins.add(vid)
        self._released.add(vid)

    # ------------------------------------------------------------------ close
    def close(self) -> None:
        """Close libsumo (the next provider in this process starts a fresh SUMO)."""
        if self.closed:
            return
        self.closed = True
        self._finalizer()  # closes libsumo if it was started and removes the route file


def _check_net_file(net_file: Path, road_map: RoadMap) -> None:
    """The SUMO network must be readable XML with a <net> root: SUMO crashes the whole process
    (instead of raising) on a malformed network. The file the map was compiled from is known good."""
    try:
        data = net_file.read_bytes()
    except OSError as err:
        raise ScenarioError(f"{net_file}: cannot read the SUMO network ({err.strerror})") from None
    if hashlib.sha256(data).hexdigest() == road_map.content_hash:
        return
    root_tag = None
    try:
        for event, element in ET.iterparse(io.BytesIO(data), events=("start", "end")):
            if root_tag is None:
                root_tag = element.tag
            elif event == "end":
                element.clear()
    except ET.ParseError as err:
        raise ScenarioError(f"{net_file}: the SUMO network is not valid XML ({err})") from None
    if root_tag != "net":
        raise ScenarioError(f"{net_file}: expected a SUMO network with root <net>, found <{root_tag}>")


def _shut_down(work_dir: Path, started: list[bool]) -> None:
    if started[0]:
        started[0] = False
        ls = _libsumo()
        with contextlib.suppress(ls.TraCIException, ls.FatalTraCIError):
            ls.simulation.close()
    shutil.rmtree(work_dir, ignore_errors=True)


# ---------------------------------------------------------------------------- low level
class _RawLibsumo:
    """libsumo's compiled functions, called directly in the step (no wrapper layer)."""

    def __getattr__(self, name):
        _libsumo()
        from libsumo import _libsumo as compiled

        value = getattr(compiled, name)
        setattr(self, name, value)
        return value


_C = _RawLibsumo()


def _heading_of_angle(angle_deg: float) -> float:
    """SUMO angle (degrees clockwise from north) -> heading (radians CCW from east)."""
    h = math.radians(90.0 - angle_deg)
    return math.atan2(math.sin(h), math.cos(h))


_X, _Y, _HEADING, _SPEED = COLUMN["x"], COLUMN["y"], COLUMN["heading"], COLUMN["speed"]
_ACCEL, _JERK, _LAT, _YAW = COLUMN["accel"], COLUMN["jerk"], COLUMN["lat_accel"], COLUMN["yaw_rate"]
_LENGTH = COLUMN["length"]
_AGENT, _SOCIAL_AGENT = int(Role.AGENT), int(Role.SOCIAL_AGENT)


@njit(nogil=True)
def _twin_rows(alive, owner, role, me):  # pragma: no cover - compiled
    """Rows of agent vehicles (AGENT / SOCIAL_AGENT roles) that another provider owns."""
    out = np.empty(alive.shape[0], dtype=np.int64)
    n = 0
    for r in range(alive.shape[0]):
        if alive[r] and owner[r] != me and (role[r] == _AGENT or role[r] == _SOCIAL_AGENT):
            out[n] = r
            n += 1
    return out[:n]


@njit(nogil=True)
def _twin_poses(data, rows):  # pragma: no cover - compiled
    """float64[n, 4]: front-bumper x, y, SUMO angle (degrees) and speed (>= 0) of table rows."""
    out = np.empty((rows.shape[0], 4))
    for i in range(rows.shape[0]):
        r = rows[i]
        h = data[_HEADING, r]
        half = 0.5 * data[_LENGTH, r]
        out[i, 0] = data[_X, r] + half * math.cos(h)
        out[i, 1] = data[_Y, r] + half * math.sin(h)
        out[i, 2] = (90.0 - math.degrees(h)) % 360.0
        out[i, 3] = max(data[_SPEED, r], 0.0)
    return out


@njit(nogil=True)
def _write_states(data, rows, pos, angle, speed, dt, front_offset):  # pragma: no cover - compiled
    """Write SUMO readings (flat x0 y0 x1 y1 ..., angles in degrees, speeds) into table rows.

    The box centre lies ``front_offset * length`` behind the reported point. Acceleration, jerk,
    yaw rate and lateral acceleration are differences against the row's previous state (a row
    added this step already holds the same reading, so its differences are 0).
    """
    inv_dt = 1.0 / dt
    for i in range(rows.shape[0]):
        r = rows[i]
        h = math.radians(90.0 - angle[i])
        h = math.atan2(math.sin(h), math.cos(h))
        back = front_offset * data[_LENGTH, r]
        d_h = h - data[_HEADING, r]
        yaw_rate = math.atan2(math.sin(d_h), math.cos(d_h)) * inv_dt
        accel = (speed[i] - data[_SPEED, r]) * inv_dt
        data[_JERK, r] = (accel - data[_ACCEL, r]) * inv_dt
        data[_X, r] = pos[2 * i] - back * math.cos(h)
        data[_Y, r] = pos[2 * i + 1] - back * math.sin(h)
        data[_HEADING, r] = h
        data[_SPEED, r] = speed[i]
        data[_ACCEL, r] = accel
        data[_YAW, r] = yaw_rate
        data[_LAT, r] = speed[i] * yaw_rate
