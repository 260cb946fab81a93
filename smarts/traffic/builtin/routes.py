"""Routes of the built-in traffic model as per-lane "slots" that the compiled step walks.

A route is a sequence of non-junction roads. For every lane on those roads (and every junction
lane the route uses between them) it gets a slot: which slot follows at the lane's end, which
slots lie left and right (lane changes), and how many lane changes are still needed from there
to stay on the route (``cost``) with the direction of the first one (``dir``). A vehicle holds its
slot and its arc length on the slot's lane, so following a route, changing lanes and looking
ahead are array lookups. Slots of all routes live in one set of flat arrays.
"""

from __future__ import annotations

import copy
import heapq
import itertools
import math

import numpy as np

from smarts.core.errors import ScenarioError
from smarts.maps import RoadMap, extend_route
from smarts.traffic.density import lane_exits, road_links

NEXT_NONE = -1  # the lane does not continue on the route: change lanes before its end
NEXT_ARRIVE = -2  # the route ends at this lane's end
NO_WAY = 1000.0  # cost of a lane from which the route cannot be followed
MINOR_MERGE_COST = 1.5
"""Extra cost of a lane that continues only by merging without right of way (an acceleration
lane): more than one lane change, so vehicles move over when there is a neighbour lane, but may
stay when no gap opens (the lane still continues)."""
U_TURN_COST = 1000.0  # metres added to a U-turn link when completing a route between two roads
ENDLESS_LENGTH = 1e9  # extend_route: follow successors until a dead end


class RouteTable:
    """All routes of one provider, as flat slot arrays (see the module docstring)."""

    def __init__(self, road_map: RoadMap):
        self.map = road_map
        self.links = road_links(road_map)
        self.exits = lane_exits(road_map)
        self._minor, self._road_lanes, self._road_length = _road_tables(road_map)
        self.routes: list[tuple[int, ...]] = []  # road sequence per route
        self.slot_of: list[dict[int, int]] = []  # per route: lane -> slot
        self._key: dict[tuple, int] = {}
        self._lane: list[int] = []
        self._next: list[int] = []
        self._left: list[int] = []
        self._right: list[int] = []
        self._dir: list[int] = []
        self._cost: list[float] = []
        self.pack_count = 0  # how often the flat arrays were built (once per batch of routes)
        self._packed: tuple[np.ndarray, np.ndarray] | None = None

    def copy(self) -> RouteTable:
        """A table with these routes that adds its own: routes are only ever appended and a built
        route's slots never change, so the copy's lists start as copies and the rest is shared."""
        new = copy.copy(self)
        for name in ("routes", "slot_of", "_lane", "_next", "_left", "_right", "_dir", "_cost"):
            setattr(new, name, list(getattr(self, name)))
        new._key = dict(self._key)
        return new

    # ------------------------------------------------------------------ arrays
    @property
    def slot_int(self) -> np.ndarray:
        """int64[5, slots]: lane, next, left, right and direction of every slot."""
        return (self._packed or self.pack())[0]

    @property
    def slot_cost(self) -> np.ndarray:
        """float64[slots]: lane changes still needed from each slot."""
        return (self._packed or self.pack())[1]

    def pack(self) -> tuple[np.ndarray, np.ndarray]:
        """Build the flat arrays the kernels read. Adding routes only appends to lists and
        marks the arrays stale; they are built on the next read, so building n routes costs
        O(n) instead of one repack of every slot per route."""
        slot_int = np.array([self._lane, self._next, self._left, self._right, self._dir], dtype=np.int64).reshape(5, -1)
        self._packed = (slot_int, np.array(self._cost, dtype=np.float64))
        self.pack_count += 1
        return self._packed

    # ------------------------------------------------------------------ road sequences
    def road_index(self, road_id: str, where: str) -> int:
        m = self.map
        if road_id not in m.road_index_of:
            raise ScenarioError(f"{where}: unknown road {road_id!r} (map {m.source!r})")
        road = m.road_index_of[road_id]
        if m.lane_internal[self._road_lanes[road]].any():
            raise ScenarioError(f"{where}: road {road_id!r} lies inside a junction; name the roads around it")
        return road

    def complete(self, roads: list[int], where: str) -> list[int]:
        """Fill the gaps between consecutive roads with shortest road paths."""
        full = [roads[0]]
        for a, b in itertools.pairwise(roads):
            if b == full[-1]:
                continue
            if b in self.links.get(a, {}):
                full.append(b)
                continue
            path = self._shortest(a, b)
            if path is None:
                m = self.map
                raise ScenarioError(f"{where}: road {m.road_ids[a]!r} does not connect to {m.road_ids[b]!r}")
            full.extend(path[1:])
        return full

    def _shortest(self, a: int, b: int) -> list[int] | None:
        road_length = self._road_length
        best = {a: 0.0}
        prev: dict[int, int] = {}
        heap = [(0.0, a)]
        while heap:
            d, road = heapq.heappop(heap)
            if road == b:
                path = [b]
                while path[-1] != a:
                    path.append(prev[path[-1]])
                return path[::-1]
            if d > best.get(road, math.inf):
                continue
            for nxt, u_turn in self.links.get(road, {}).items():
                nd = d + road_length[nxt] + (U_TURN_COST if u_turn else 0.0)
                if nd < best.get(nxt, math.inf):
                    best[nxt] = nd
                    prev[nxt] = road
                    heapq.heappush(heap, (nd, nxt))
        return None

    # ------------------------------------------------------------------ routes
    def add_roads(self, road_ids: list[str], where: str) -> int:
        """Route id for a list of road ids (consecutive or just passing points, in order)."""
        if not road_ids:
            raise ScenarioError(f"{where}: a route needs at least one road")
        roads = [self.road_index(r, f"{where}[{i}]" if len(road_ids) > 1 else where) for i, r in enumerate(road_ids)]
        full = self.complete(roads, where)
        seen: set[int] = set()
        for road in full:
            if road in seen:
                raise ScenarioError(
                    f"{where}: the route passes road {self.map.road_ids[road]!r} twice; "
                    "the built-in engine needs routes without loops"
                )
            seen.add(road)
        return self.add(full)

    def add_from_lane(self, lane: int) -> int:
        """Route from ``lane`` (possibly inside a junction) along the straightest successors to
        a lane that leads nowhere: for vehicles adopted mid-drive."""
        key = ("lane", int(lane))
        if key in self._key:
            return self._key[key]
        lanes = [int(x) for x in extend_route(self.map, int(lane), ENDLESS_LENGTH)]
        internal = self.map.lane_internal
        lead = []
        while lanes and internal[lanes[0]]:
            lead.append(lanes.pop(0))
        roads: list[int] = []
        for ln in lanes:
            if not internal[ln]:
                r = int(self.map.lane_road[ln])
                if r in roads[:-1]:
                    break  # a ring road: stop before the loop closes
                if not roads or roads[-1] != r:
                    roads.append(r)
        if roads:
            route = self.add(roads)
            if lead:
                route = self._with_lead(route, lead, lanes[0])
        else:  # a junction lane that leads nowhere: a route of junction lanes only
            route = self._junction_only(lead)
        self._key[key] = route
        return route

    def add(self, roads: list[int]) -> int:
        key = tuple(roads)
        if key in self._key:
            return self._key[key]
        route = len(self.routes)
        self.routes.append(key)
        self.slot_of.append({})
        self._build(route, roads)
        self._key[key] = route
        self._packed = None
        return route

    def _new_slot(self, route: int, lane: int, cost: float, direction: int) -> int:
        slot = len(self._lane)
        self.slot_of[route][lane] = slot
        self._lane.append(lane)
        self._next.append(NEXT_NONE)
        self._left.append(-1)
        self._right.append(-1)
        self._dir.append(direction)
        self._cost.append(cost)
        return slot

    def _build(self, route: int, roads: list[int]) -> None:
        m = self.map
        lanes_of = [self._road_lanes[r] for r in roads]
        cost: dict[int, float] = {lane: 0.0 for lane in lanes_of[-1]}
        way: dict[int, tuple[tuple[int, ...], int] | None] = {}
        for lane in lanes_of[-1]:
            way[lane] = None
        for k in range(len(roads) - 2, -1, -1):
            target_road = roads[k + 1]
            cont: dict[int, float] = {}
            for lane in lanes_of[k]:
                options = [
                    (cost[t] + (MINOR_MERGE_COST if path and path[0] in self._minor else 0.0), len(path), t, path)
                    for path, t in self.exits[lane]
                    if int(m.lane_road[t]) == target_road
                ]
                if options:
                    c, _, t, path = min(options)
                    cont[lane] = c
                    way[lane] = (path, t)
                else:
                    cont[lane] = NO_WAY
                    way[lane] = None
            for lane in lanes_of[k]:
                cost[lane] = self._best_lane(lanes_of[k], lane, cont)[0]
        # Slots: road lanes first, then the junction lanes the chosen ways pass.
        direction: dict[int, int] = {}
        for k, lanes in enumerate(lanes_of):
            cont = {ln: (cost[ln] if k == len(roads) - 1 else self._cont_cost(ln, way, cost)) for ln in lanes}
            for lane in lanes:
                direction[lane] = self._best_lane(lanes, lane, cont)[1]
        for k, lanes in enumerate(lanes_of):
            for lane in lanes:
                self._new_slot(route, lane, cost[lane], direction[lane])
        slots = self.slot_of[route]
        for k, lanes in enumerate(lanes_of):
            last = k == len(roads) - 1
            for lane in lanes:
                s = slots[lane]
                left, right = int(m.lane_left[lane]), int(m.lane_right[lane])
                self._left[s] = slots.get(left, -1) if left >= 0 else -1
                self._right[s] = slots.get(right, -1) if right >= 0 else -1
                if last:
                    self._next[s] = NEXT_ARRIVE
                    continue
                chosen = way[lane]
                if chosen is None:
                    continue
                path, target = chosen
                prev = s
                for jl in path:
                    j = slots.get(jl)
                    if j is None:
                        j = self._new_slot(route, jl, cost[target], 0)
                    self._next[prev] = j
                    prev = j
                self._next[prev] = slots[target]

    def _cont_cost(self, lane: int, way: dict, cost: dict) -> float:
        chosen = way.get(lane)
        if chosen is None:
            return NO_WAY
        path, target = chosen
        return cost[target] + (MINOR_MERGE_COST if path and path[0] in self._minor else 0.0)

    def _best_lane(self, lanes: list[int], lane: int, cont: dict[int, float]) -> tuple[float, int]:
        """(cost, direction of the first change) from ``lane`` given each lane's cost to continue."""
        idx = {ln: int(self.map.lane_index[ln]) for ln in lanes}
        best = (cont[lane], 0, 0)
        for other in lanes:
            diff = idx[other] - idx[lane]
            c = cont[other] + abs(diff)
            if (c, abs(diff)) < (best[0], best[1]):
                best = (c, abs(diff), int(np.sign(diff)))
        return min(best[0], NO_WAY), best[2]

    def _with_lead(self, route: int, lead: list[int], first: int) -> int:
        """A copy of ``route`` reached through junction lanes ``lead`` (a separate route id)."""
        new = len(self.routes)
        self.routes.append(self.routes[route] + (-1,) + tuple(lead))
        self.slot_of.append({})
        old_slots = self.slot_of[route]
        remap = {}
        for lane, s in old_slots.items():
            remap[s] = self._new_slot(new, lane, self._cost[s], self._dir[s])
        for s, t in remap.items():
            for arr in (self._next, self._left, self._right):
                arr[t] = remap.get(arr[s], arr[s]) if arr[s] >= 0 else arr[s]
        target_cost = self._cost[remap[old_slots[first]]]
        prev = None
        for lane in lead:
            j = self._new_slot(new, lane, target_cost, 0)
            if prev is not None:
                self._next[prev] = j
            prev = j
        self._next[prev] = self.slot_of[new][first]
        self._packed = None
        return new

    def _junction_only(self, lead: list[int]) -> int:
        new = len(self.routes)
        self.routes.append((-1,) + tuple(lead))
        self.slot_of.append({})
        prev = None
        for lane in lead:
            j = self._new_slot(new, lane, 0.0, 0)
            if prev is not None:
                self._next[prev] = j
            prev = j
        self._next[prev] = NEXT_ARRIVE
        self._packed = None
        return new

    # ------------------------------------------------------------------ queries
    def lanes_of_first_road(self, route: int) -> list[int]:
        """Lanes of the route's first road, rightmost first."""
        return list(self._road_lanes[self.routes[route][0]])

    def slot(self, route: int, lane: int) -> int:
        return self.slot_of[route][lane]


def _road_tables(road_map: RoadMap) -> tuple[frozenset[int], list[list[int]], np.ndarray]:
    """What routing reads of the map alone: the minor merge lanes (:func:`_minor_merge_lanes`),
    each road's lanes (rightmost first; ``RoadMap.road_lanes`` scans every lane per call) and
    its mean lane length. Cached on the map instance (as the junction table is), so the
    providers of a batch's episodes on one map build them once."""
    cached = road_map.__dict__.get("_route_road_tables")
    if cached is not None:
        return cached
    order = np.lexsort((road_map.lane_index, road_map.lane_road))
    bounds = np.searchsorted(road_map.lane_road[order], np.arange(len(road_map.road_ids) + 1))
    road_lanes = [order[bounds[r] : bounds[r + 1]].tolist() for r in range(len(road_map.road_ids))]
    road_length = np.array([float(road_map.lane_length[lanes].mean()) if lanes else 0.0 for lanes in road_lanes])
    road_length.flags.writeable = False
    tables = (_minor_merge_lanes(road_map), road_lanes, road_length)
    road_map.__dict__["_route_road_tables"] = tables
    return tables


def _minor_merge_lanes(m: RoadMap) -> frozenset[int]:
    """First junction lanes of connections without right of way into a lane others also enter
    (merging from an acceleration lane or a side road)."""
    if len(m.conn_from) == 0:
        return frozenset()
    entering: dict[int, int] = {}
    for to in m.conn_to:
        entering[int(to)] = entering.get(int(to), 0) + 1
    return frozenset(
        int(via)
        for via, to, major in zip(m.conn_via, m.conn_to, m.conn_major)
        if via >= 0 and not major and entering[int(to)] > 1
    )
