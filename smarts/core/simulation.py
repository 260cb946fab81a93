"""The step loop: clock, providers, map state, events and route progress for all agents at once.

Step order: clock += dt; providers step (the agent provider applies this step's actions first);
every live vehicle is projected onto the map; events are computed for the agents; route progress is
tracked. Observations and rewards are built from this state by ``smarts.sensors`` and ``smarts.env``.
The simulation knows providers only through ``smarts.core.provider.Provider``, so agents, traffic and
replay plug in without the loop importing them.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from smarts.core.events import NUM_EVENTS, Event, NotMovingTracker, box_collisions, wrong_way
from smarts.core.missions import GOAL_POSITION, GOAL_ROAD, MissionArrays, ResolvedMission, stack_missions
from smarts.core.provider import Provider
from smarts.core.vehicle_table import VehicleTable
from smarts.maps import RoadMap, on_road, project

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
        self.seed = int(seed)
        self.event_config = events or EventConfig(terminate_on=_default_terminations())
        self.table = VehicleTable(capacity)
        self.missions = missions
        self.mission_arrays: MissionArrays = stack_missions(road_map, missions)
        self.agent_ids: list[str] = [m.agent_id for m in missions]
        self.agent_index = {a: i for i, a in enumerate(self.agent_ids)}
        n = len(missions)
        self.agent_row = np.full(n, -1, dtype=np.int64)
        self.agent_active = np.zeros(n, dtype=bool)
        self.agent_events = np.zeros((n, NUM_EVENTS), dtype=bool)
        self.agent_done = np.zeros(n, dtype=bool)
        self.route_index = np.zeros(n, dtype=np.int64)  # nearest route point
        self.route_progress = np.zeros(n)  # arc length along the route path
        self.route_progress_delta = np.zeros(n)
        self.not_moving = NotMovingTracker(
            capacity, self.event_config.not_moving_seconds, self.event_config.not_moving_distance
        )
        self.providers: list[Provider] = []
        for p in providers:
            self.add_provider(p)
        self.actions: dict[str, np.ndarray] = {}
        self.time = 0.0
        self.step_count = 0
        self.rng = np.random.default_rng(self.seed)
        self._window = np.arange(-ROUTE_WINDOW_BACK, ROUTE_WINDOW_AHEAD + 1)

    # ------------------------------------------------------------------ providers
    def add_provider(self, provider: Provider) -> None:
        provider.provider_id = len(self.providers)
        self.providers.append(provider)

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
            self.seed = int(seed)
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
        for p in self.providers:
            p.reset(self)
        missing = [a for a, r in zip(self.agent_ids, self.agent_row) if r < 0]
        if missing:
            raise RuntimeError(f"no provider created a vehicle for agents {missing}")
        self.agent_active[:] = True
        rows = self.table.alive_rows
        self.not_moving.reset_rows(rows, self.table.x[rows], self.table.y[rows], 0.0)
        self._update_map_state()
        self._update_route_progress(first=True)
        self._update_events()

    def register_agent_vehicle(self, agent_id: str, row: int) -> None:
        self.agent_row[self.agent_index[agent_id]] = row

    def step(self, actions: dict[str, np.ndarray]) -> None:
        """Advance one step. ``actions`` maps active agent ids to their action arrays."""
        self.time += self.dt
        self.step_count += 1
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
            for owner in np.unique(self.table.owner[rows]):
                if owner >= 0:
                    self.providers[owner].release(self, rows[self.table.owner[rows] == owner])
            self.table.remove(rows)
            self.agent_active[finished] = False
        return finished

    def close(self) -> None:
        for p in self.providers:
            p.close()

    # ------------------------------------------------------------------ per-step state
    @property
    def active_agents(self) -> np.ndarray:
        return np.flatnonzero(self.agent_active)

    def _update_map_state(self) -> None:
        t = self.table
        rows = t.alive_rows
        if rows.size == 0:
            return
        xy = np.stack([t.x[rows], t.y[rows]], axis=1)
        proj = project(self.road_map, xy, t.heading[rows])
        t.lane[rows] = proj.lane
        t.s[rows] = proj.s
        t.t[rows] = proj.t
        t.lane_heading[rows] = proj.lane_heading
        t.lane_distance[rows] = proj.distance

    def _update_route_progress(self, first: bool) -> None:
        """Track each agent's nearest point on its route path within a small moving window."""
        agents = self.active_agents
        if agents.size == 0:
            self.route_progress_delta[:] = 0.0
            return
        ma = self.mission_arrays
        rows = self.agent_row[agents]
        x, y = self.table.x[rows], self.table.y[rows]
        if first:
            idx = np.zeros(len(agents), dtype=np.int64)
            window = np.arange(0, min(ma.path_s.shape[1], 4 * ROUTE_WINDOW_AHEAD))[None, :]
            cand = np.minimum(window, ma.path_len[agents, None] - 1)
        else:
            idx = self.route_index[agents]
            cand = np.clip(idx[:, None] + self._window[None, :], 0, ma.path_len[agents, None] - 1)
        pts = ma.paths[agents[:, None], 0, cand]  # [n, w, 3]
        d2 = (pts[..., 0] - x[:, None]) ** 2 + (pts[..., 1] - y[:, None]) ** 2
        best = cand[np.arange(len(agents)), d2.argmin(axis=1)]
        p = ma.paths[agents, 0, best]
        along = (x - p[:, 0]) * np.cos(p[:, 2]) + (y - p[:, 1]) * np.sin(p[:, 2])
        progress = np.clip(ma.path_s[agents, best] + along, 0.0, ma.route_length[agents])
        self.route_progress_delta[:] = 0.0
        if not first:
            self.route_progress_delta[agents] = progress - self.route_progress[agents]
        self.route_progress[agents] = progress
        self.route_index[agents] = best

    def _update_events(self) -> None:
        t = self.table
        rm = self.road_map
        ev = self.agent_events
        ev[:] = False
        agents = self.active_agents
        if agents.size == 0:
            return
        rows = self.agent_row[agents]
        alive = t.alive_rows
        # Collisions against every live vehicle, pedestrians included.
        corners = t.corners(alive)
        radius = 0.5 * np.hypot(t.length[alive], t.width[alive])
        hit = box_collisions(corners, t.x[alive], t.y[alive], radius)
        row_pos = np.searchsorted(alive, rows)
        ev[agents, Event.COLLISION] = hit[row_pos]
        # Road surface: centre and four corners in one raster lookup.
        agent_corners = corners[row_pos]
        pts = np.concatenate([np.stack([t.x[rows], t.y[rows]], axis=1)[:, None], agent_corners], axis=1)
        surface = on_road(rm, pts)  # [n, 5]
        ev[agents, Event.OFF_ROAD] = ~surface[:, 0]
        ev[agents, Event.PARTIAL_OFF_ROAD] = ~surface.all(axis=1)
        lane = t.lane[rows]
        ev[agents, Event.WRONG_WAY] = wrong_way(t.heading[rows], t.lane_heading[rows], lane, rm.lane_internal)
        ma = self.mission_arrays
        safe_lane = np.maximum(lane, 0)
        road = rm.lane_road[safe_lane]
        on_route = ma.on_route_road[agents, road] | rm.lane_internal[safe_lane]
        ev[agents, Event.OFF_ROUTE] = (lane >= 0) & ~on_route
        # Goals.
        kind = ma.goal_kind[agents]
        gd = np.hypot(t.x[rows] - ma.goal_xy[agents, 0], t.y[rows] - ma.goal_xy[agents, 1])
        reached_pos = (kind == GOAL_POSITION) & (gd <= ma.goal_radius[agents])
        on_goal_road = (lane >= 0) & (road == ma.goal_road[agents])
        lane_ok = (ma.goal_lane[agents] < 0) | (lane == ma.goal_lane[agents])
        reached_road = (kind == GOAL_ROAD) & on_goal_road & lane_ok & (t.s[rows] >= ma.goal_s[agents])
        ev[agents, Event.REACHED_GOAL] = reached_pos | reached_road
        ev[agents, Event.NOT_MOVING] = self.not_moving.update(rows, t.x[rows], t.y[rows], self.time)
        ev[agents, Event.MAX_STEPS] = self.step_count >= self.episode_steps
        self.agent_done[agents] = (ev[agents] & self.event_config.terminate_on).any(axis=1)
        self.agent_done[agents] |= ev[agents, Event.MAX_STEPS]


def _default_terminations() -> np.ndarray:
    mask = np.zeros(NUM_EVENTS, dtype=bool)
    for e in (Event.COLLISION, Event.OFF_ROAD, Event.REACHED_GOAL, Event.MAX_STEPS):
        mask[e] = True
    return mask
