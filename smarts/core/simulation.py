"""The step loop: clock, providers, map state, events and route progress for all agents at once.

Step order: clock += dt; providers step (the agent provider applies this step's actions first);
every live vehicle is projected onto the map; events are computed for the agents; route progress is
tracked. Observations and rewards are built from this state by ``smarts.sensors`` and ``smarts.env``.
The simulation knows providers only through ``smarts.core.provider.Provider``, so agents, traffic and
replay plug in without the loop importing them.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numba
import numpy as np

from smarts.core.events import NUM_EVENTS, Event, NotMovingTracker, agent_events
from smarts.core.missions import MissionArrays, ResolvedMission, stack_missions
from smarts.core.provider import Provider, ProviderBase
from smarts.core.vehicle_table import COLUMN, Role, VehicleTable
from smarts.maps import RoadMap, project
from smarts.maps.drivable import raster_lookup

SEED_MAX = 2**64 - 1
"""The largest seed: numpy seeds with 64-bit words and ``torch.manual_seed`` takes at most this."""


def check_seed(seed: object, what: str = "seed") -> int:
    """``seed`` as a Python int, or ``ValueError`` naming ``what`` (the argument) and the value.

    A seed is an integer (Python or numpy, not bool) from 0 to ``SEED_MAX``. A float is refused
    even when whole (``1.0``), as numpy and gymnasium refuse it, so a computed seed is not silently
    truncated."""
    if isinstance(seed, (bool, np.bool_)) or not isinstance(seed, (int, np.integer)):
        kind = "a bool" if isinstance(seed, (bool, np.bool_)) else f"of type {type(seed).__name__}"
        raise ValueError(f"{what}: expected an integer from 0 to 2**64 - 1, got {seed!r} ({kind})")
    value = int(seed)
    if value < 0:
        raise ValueError(f"{what}: expected an integer from 0 to 2**64 - 1, got {value} (negative)")
    if value > SEED_MAX:
        raise ValueError(
            f"{what}: expected an integer from 0 to 2**64 - 1, got {value} (too large for numpy's "
            "seed words and torch.manual_seed)"
        )
    return value


def derived_seed(seed: int, offset: int) -> int:
    """``seed + offset`` wrapped into the seed range (episode ``k`` of a seeded run, copy ``i``...)."""
    return (int(seed) + int(offset)) % (SEED_MAX + 1)


ROUTE_WINDOW_BACK = 2  # route points searched behind the last match
ROUTE_WINDOW_AHEAD = 10  # ... and ahead of it (more than the farthest one-step move at ~1 m spacing)


@dataclass
class EventConfig:
    terminate_on: np.ndarray  # bool[NUM_EVENTS]
    not_moving_seconds: float = 60.0
    not_moving_distance: float = 1.0


class Simulation:
    """One scenario instance: a map, a vehicle table, providers and the agents' missions."""

    def __init__(
        self,
        road_map: RoadMap,
        missions: list[ResolvedMission],
        providers: list[Provider],
        *,
        dt: float = 0.1,
        episode_steps: int = 1000,
        events: EventConfig | None = None,
        capacity: int = 256,
        seed: int = 42,
    ):
        self.road_map = road_map
        self.dt = float(dt)
        self.episode_steps = int(episode_steps)
        self.seed = check_seed(seed, "Simulation(seed=...)")
        self.event_config = events or EventConfig(terminate_on=_default_terminations())
        self.table = VehicleTable(capacity)
        self.missions = missions
        self.mission_arrays: MissionArrays = stack_missions(road_map, missions)
        self.agent_ids: list[str] = [m.agent_id for m in missions]
        self.agent_index = {a: i for i, a in enumerate(self.agent_ids)}
        self.lead_ids: list[str | None] = [m.follow for m in missions]
        """Per agent, the id of the vehicle it follows (``smarts.core.following``), or None."""
        n = len(missions)
        self.agent_row = np.full(n, -1, dtype=np.int64)
        self.agent_active = np.zeros(n, dtype=bool)
        self.agent_events = np.zeros((n, NUM_EVENTS), dtype=bool)
        self.agent_done = np.zeros(n, dtype=bool)
        self.route_index = np.zeros(n, dtype=np.int64)  # nearest route point
        self.route_progress = np.zeros(n)  # arc length along the route path
        self.route_progress_delta = np.zeros(n)
        # where each agent's vehicle (row) was at the last event test: goals are tested on the
        # movement since then (a short goal lane can lie wholly inside one step's travel)
        self.agent_prev_xy = np.zeros((n, 2))
        self.agent_prev_row = np.full(n, -1, dtype=np.int64)
        self.not_moving = NotMovingTracker(
            capacity, self.event_config.not_moving_seconds, self.event_config.not_moving_distance
        )
        self.providers: list[Provider] = []
        self._checks: list = []  # providers' check_actions, called before every step
        for p in providers:
            self.add_provider(p)
        self.actions: dict[str, np.ndarray] = {}
        self.time = 0.0
        self.step_count = 0
        self.rng = np.random.default_rng(self.seed)
        self.signals = None  # a smarts.traffic.signals.SignalState when the map has signals
        self.alive = np.zeros(0, dtype=np.int64)  # live rows after the last map update
        self._active = np.zeros(0, dtype=np.int64)
        self._active_rows = np.zeros(0, dtype=np.int64)

    # ------------------------------------------------------------------ providers
    def add_provider(self, provider: Provider) -> None:
        provider.provider_id = len(self.providers)
        self.providers.append(provider)
        check = getattr(provider, "check_actions", None)  # optional part of the protocol
        if check is not None and getattr(type(provider), "check_actions", None) is not ProviderBase.check_actions:
            self._checks.append(check)

    def hand_over(self, rows: np.ndarray, to: Provider, role=None) -> None:
        """Move rows to another provider: the old owner releases them, the new one accepts them."""
        rows = np.asarray(rows, dtype=np.int64)
        ok = to.can_accept(self, rows)
        if not ok.all():
            raise ValueError(
                f"provider {to.name!r} cannot take vehicles "
                f"{[self.table.ids[r] for r in rows[~ok]]}"
            )
        for owner in np.unique(self.table.owner[rows]):
            if owner >= 0:
                self.providers[owner].release(self, rows[self.table.owner[rows] == owner])
        self.table.transfer(rows, to.provider_id, role)
        to.accept(self, rows)

    # ------------------------------------------------------------------ episode
    def reset(self, seed: int | None = None) -> None:
        if seed is not None:
            self.seed = check_seed(seed, "Simulation.reset(seed=...)")
        self.rng = np.random.default_rng(self.seed)
        self.table.clear()
        self.time = 0.0
        self.step_count = 0
        self.actions = {}
        self.agent_row[:] = -1
        self.agent_active[:] = False
        self.agent_events[:] = False
        self.agent_done[:] = False
        self.route_index[:] = 0
        self.route_progress[:] = 0.0
        self.route_progress_delta[:] = 0.0
        self.agent_prev_row[:] = -1
        for p in self.providers:
            p.reset(self)
        for p in self.providers:
            p.start(self)
        missing = [a for a, r in zip(self.agent_ids, self.agent_row) if r < 0]
        if missing:
            raise RuntimeError(f"no provider created a vehicle for agents {missing}")
        self.agent_active[:] = True
        self._refresh_active()
        rows = self.table.alive_rows
        self.not_moving.reset_rows(rows, self.table.x[rows], self.table.y[rows], 0.0)
        self._update_map_state()
        self._update_route_progress(first=True)
        self._update_events()

    def register_agent_vehicle(self, agent_id: str, row: int) -> None:
        self.agent_row[self.agent_index[agent_id]] = row

    def check_actions(self, actions: dict[str, np.ndarray], agents: np.ndarray | None = None) -> None:
        """Raise ``ActionError`` naming every agent whose action cannot be applied (missing, not
        real numbers, wrongly shaped, not finite), changing nothing. ``agents``: the agent indices
        to check (None: every active agent). ``step`` calls this before anything moves."""
        for check in self._checks:
            check(self, actions, agents)

    def step(self, actions: dict[str, np.ndarray]) -> None:
        """Advance one step. ``actions`` maps active agent ids to their action arrays.

        Atomic: every action is checked first (``check_actions``); a refused step raises
        ``ActionError`` and changes nothing (no vehicle, controller, traffic, clock or step count).
        """
        self.check_actions(actions)
        self.step_count += 1
        self.time = self.step_count * self.dt  # no drift from summing dt
        self.actions = actions
        for p in self.providers:
            p.step(self, self.dt)
        self._update_map_state()
        self._update_route_progress(first=False)
        self._update_events()

    def remove_done_agents(self) -> np.ndarray:
        """Remove the vehicles of agents that finished this step; returns their agent indices."""
        finished = np.flatnonzero(self.agent_active & self.agent_done)
        if finished.size:
            rows = self.agent_row[finished]
            to_traffic = np.array([self.missions[a].on_end == "traffic" for a in finished])
            if to_traffic.any():
                self._hand_back(rows[to_traffic])
                rows = rows[~to_traffic]
            for owner in np.unique(self.table.owner[rows]):
                if owner >= 0:
                    self.providers[owner].release(self, rows[self.table.owner[rows] == owner])
            self.table.remove(rows)
            self.agent_active[finished] = False
            self._refresh_active()
        return finished

    def _hand_back(self, rows: np.ndarray) -> None:
        """Give finished agents' vehicles to the first provider that takes them (traffic)."""
        for row in rows.tolist():
            owner = self.table.owner[row]
            for p in self.providers:
                if p.provider_id != owner and p.can_accept(self, np.array([row]))[0]:
                    self.hand_over(np.array([row]), p, Role.TRAFFIC)
                    break
            else:
                raise RuntimeError(
                    f"{self.table.ids[row]}: mission.on_end is 'traffic' but no traffic provider "
                    "can take the vehicle (the scenario needs a traffic section)"
                )

    def close(self) -> None:
        for p in self.providers:
            p.close()

    # ------------------------------------------------------------------ per-step state
    @property
    def active_agents(self) -> np.ndarray:
        """Indices of the agents still in the episode (cached; refreshed when agents leave)."""
        return self._active

    @property
    def active_rows(self) -> np.ndarray:
        """Table rows of ``active_agents``, in the same order."""
        return self._active_rows

    def _refresh_active(self) -> None:
        self._active = np.flatnonzero(self.agent_active)
        self._active_rows = self.agent_row[self._active]

    def _update_map_state(self) -> None:
        t = self.table
        rows = t.alive_rows
        self.alive = rows
        if rows.size == 0:
            return
        proj = project(self.road_map, t.data[_XY][:, rows].T, t.heading[rows])
        t.lane[rows] = proj.lane
        t.data[_LANE_STATE[:, None], rows] = (proj.s, proj.t, proj.lane_heading, proj.distance)

    def _update_route_progress(self, first: bool) -> None:
        """Track each agent's nearest point on its route path within a small moving window."""
        self.route_progress_delta[:] = 0.0
        ma = self.mission_arrays
        _route_progress(
            self.table.data, self._active, self._active_rows, ma.flat_paths, ma.stride, ma.path_len,
            ma.path_s, ma.route_length, self.route_index, self.route_progress,
            self.route_progress_delta, first,
        )

    def _update_events(self) -> None:
        ma = self.mission_arrays
        origin, inv_res, cell_max, width, flat = raster_lookup(self.road_map)
        self.agent_events[~self.agent_active] = False
        agent_events(
            self.table.data, self.table.lane, self.alive, self._active, self._active_rows,
            flat, width, origin, inv_res, cell_max,
            self.road_map.lane_internal, self.road_map.lane_road, ma.on_route_road,
            ma.goal_kind, ma.goal_xy, ma.goal_radius, ma.goal_road, ma.goal_lane, ma.goal_s,
            ma.goal_gate, self.agent_prev_xy, self.agent_prev_row,
            self.not_moving.anchor, self.not_moving.anchor_time,
            self.not_moving.seconds, self.not_moving.distance, self.time,
            self.step_count >= self.episode_steps, self.event_config.terminate_on,
            self.agent_events, self.agent_done,
        )


@numba.njit(cache=True, nogil=True)
def _route_progress(
    data, agents, rows, flat_paths, stride, path_len, path_s, route_length,
    route_index, route_progress, delta, first,
):  # pragma: no cover - compiled
    """Nearest route point in a window around the last one, and the arc length reached."""
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
        if not first:
            delta[a] = progress - route_progress[a]
        route_progress[a] = progress
        route_index[a] = best


_X, _Y = COLUMN["x"], COLUMN["y"]
_XY = [COLUMN["x"], COLUMN["y"]]
_LANE_STATE = np.array([COLUMN[c] for c in ("s", "t", "lane_heading", "lane_distance")])


def _default_terminations() -> np.ndarray:
    mask = np.zeros(NUM_EVENTS, dtype=bool)
    for e in (Event.COLLISION, Event.OFF_ROAD, Event.REACHED_GOAL, Event.MAX_STEPS):
        mask[e] = True
    return mask
