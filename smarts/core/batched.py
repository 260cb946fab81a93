"""B independent episodes stepped as one simulation: one vehicle table, one call per stage.

The episodes' vehicles live in one stacked ``VehicleTable`` of ``B * capacity`` rows: episode ``b``
owns rows ``b * capacity`` to ``(b + 1) * capacity`` (its *block*; ``row // capacity`` is the
episode index). Agents are stacked the same way: the union's agent ``a`` belongs to episode
``agent_episode[a]`` and the agents of one episode are consecutive. Every stage that is written
per row or per agent therefore runs once for the whole batch:

- the agent provider (dynamics, lane-relative control) over all agents of all episodes;
- map projection of every live row and route progress of every agent;
- events, with the pair tests (collisions) restricted to the agent's own episode: one compiled
  call walks the episodes and hands each one's rows to the single-episode kernel
  (``smarts.core.events.agent_events``), so the per-episode rules are literally the same code.

Each episode also has providers of its own (built-in traffic with its departures and random
stream, fixed-time signals). They see an :class:`EpisodeView`: the episode's block of the table as
a ``VehicleTable`` of ``capacity`` rows (views, no copies), its clock and its seed, so they run
unchanged and give the same vehicles as in a single simulation. They step one episode at a time,
unless a *batch stage* (``add_batch_stage``) steps a kind of them for all episodes at once (the
env layer's built-in traffic stage does).

The episodes may run on different maps: the maps are stacked into one lane index space
(``smarts.maps.stack``), so lane-indexed stages do not care, and the two spatial lookups (lane
projection, the drivable raster of the on-road tests) take each row's map from its episode
(``episode_map``). Each episode's providers see its map's *window* (its map in the stacked indices).

Each episode keeps its own clock, step count and seed and is reset on its own
(:meth:`BatchedSimulation.reset_episodes`) while the others go on; episode ``b`` reset with seed
``s`` follows the same trajectory as a single ``Simulation`` reset with seed ``s`` given the same
actions. The layout is plain arrays indexed by row and agent, with nothing tied to a device.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence

import numba
import numpy as np

from smarts.core.events import agent_events
from smarts.core.missions import ResolvedMission
from smarts.core.provider import Provider
from smarts.core.simulation import EventConfig, Simulation, _route_progress, check_seed, derived_seed
from smarts.core.vehicle_table import VehicleTable
from smarts.maps import RoadMap
from smarts.maps.stack import MapStack, stack_maps


def block_view(table: VehicleTable, start: int, stop: int) -> VehicleTable:
    """A ``VehicleTable`` over rows ``start:stop`` of ``table``: its arrays are views (writes go to
    ``table``), its id map is its own. Row ``r`` of the view is row ``start + r`` of ``table``."""
    view = VehicleTable.__new__(VehicleTable)
    view.capacity = stop - start
    view.data = table.data[:, start:stop]
    for i, name in enumerate(VehicleTable.FLOAT_COLUMNS):
        setattr(view, name, view.data[i])
    for name in ("lane", "role", "vtype", "owner", "alive", "serial"):
        setattr(view, name, getattr(table, name)[start:stop])
    view.serial_counter = table.serial_counter
    view.ids = [None] * view.capacity
    view.row_of = {}
    return view


def gather_xy(table: VehicleTable, rows: np.ndarray) -> np.ndarray:
    """float64[n, 2] positions of ``rows`` (gathered per column: indexing ``data`` by column first
    would copy the whole columns of every episode)."""
    xy = np.empty((len(rows), 2))
    xy[:, 0] = table.x[rows]
    xy[:, 1] = table.y[rows]
    return xy


@dataclasses.dataclass
class EpisodeView:
    """What an episode's own providers see of the batch: the attributes of ``Simulation`` they
    read (``table``, ``time``, ``step_count``, ``seed``, ``dt``, ``road_map``, ``signals``)."""

    table: VehicleTable
    road_map: RoadMap
    dt: float
    seed: int
    signals: object = None
    time: float = 0.0
    step_count: int = 0


class _EpisodeRows:
    """``table.row_of`` of the stacked table: keys are ``(episode, vehicle id)`` (the form of
    ``BatchedSimulation.lead_ids``), values the stacked row; ids live in the episode views."""

    def __init__(self, sim: "BatchedSimulation"):
        self.sim = sim

    def get(self, key, default=None):
        b, vid = key
        row = self.sim.views[b].table.row_of.get(vid)
        return default if row is None else row + b * self.sim.episode_capacity

    def __len__(self) -> int:
        return sum(len(v.table.row_of) for v in self.sim.views)


class _OffsetRows:
    """An episode's id -> row map in stacked rows."""

    def __init__(self, rows: dict, offset: int):
        self.rows, self.offset = rows, offset

    def get(self, vid, default=None):
        row = self.rows.get(vid)
        return default if row is None else row + self.offset

    def __contains__(self, vid) -> bool:
        return vid in self.rows

    def __len__(self) -> int:
        return len(self.rows)


class _EpisodeTable:
    """The stacked table with episode ``b``'s id map (rows are stacked rows)."""

    def __init__(self, sim: "BatchedSimulation", b: int):
        self._table = sim.table
        self.row_of = _OffsetRows(sim.views[b].table.row_of, b * sim.episode_capacity)

    def __getattr__(self, name: str):
        return getattr(self._table, name)


class EpisodeSim:
    """Episode ``b`` of a batch as a single simulation, for per-episode readers of a simulation
    (the benchmark's ``EpisodeRecorder``): the episode's clock, its agents by their own ids
    (``agent_index`` maps them to the batch's agent indices), their leads by vehicle id, and the
    stacked arrays. Everything else is the batch's."""

    def __init__(self, sim: "BatchedSimulation", b: int):
        self._sim, self._b = sim, b
        agents = sim.episode_agents(b).tolist()
        self.agent_index = {sim.local_agent_ids[a]: a for a in agents}
        self.lead_ids = [m.follow for m in sim.missions]
        self.table = _EpisodeTable(sim, b)
        self.road_map = sim.views[b].road_map  # its map, in the batch's lane indices

    @property
    def time(self) -> float:
        return float(self._sim.episode_time[self._b])

    @property
    def step_count(self) -> int:
        return int(self._sim.episode_step[self._b])

    def __getattr__(self, name: str):
        return getattr(self._sim, name)


class BatchedSimulation(Simulation):
    """``B`` episodes of scenarios as one ``Simulation`` of all their agents.

    ``road_map``: the map of every episode, or a ``MapStack`` of several with ``episode_map[b]``
    the map of episode ``b`` (missions and providers then use the stack's windows and stacked
    lane indices; ``self.road_map`` is the stack's combined map).

    ``episode_missions[b]``: the missions of episode ``b`` (agent ids as in its scenario; the
    union's ids are ``"<b>/<agent id>"``). ``providers``: providers of the whole batch (the agent
    provider), whose reset is per episode (``reset_episode(sim, b, agents)``). ``episode_providers[b]``:
    episode ``b``'s other providers (traffic, signals), stepped on its :class:`EpisodeView`.
    ``signals[b]``: episode ``b``'s ``SignalState`` (None without signals); its colours are moved
    into row ``b`` of ``self.via_colour``, so observations read every episode's signals in one call.
    ``step`` takes the actions of all agents as one array (``action_array``); an episode whose
    agents have all finished keeps stepping its own providers (its traffic drives on) until
    ``reset_episodes`` starts it again (``BatchedDriving`` resets such episodes at once).
    """

    def __init__(
        self,
        road_map: RoadMap | MapStack,
        episode_missions: Sequence[Sequence[ResolvedMission]],
        providers: list[Provider],
        episode_providers: Sequence[list[Provider]],
        *,
        dt: float,
        episode_steps: Sequence[int],
        events: EventConfig,
        capacity: int,
        seeds: Sequence[int],
        signals: Sequence[object] | None = None,
        episode_map: Sequence[int] | None = None,
    ):
        n_episodes = len(episode_missions)
        if n_episodes == 0:
            raise ValueError("BatchedSimulation needs at least one episode")
        self.map_stack = road_map if isinstance(road_map, MapStack) else stack_maps([road_map])
        self.episode_map = np.zeros(n_episodes, dtype=np.int64) if episode_map is None else np.asarray(episode_map, dtype=np.int64)
        if self.episode_map.shape != (n_episodes,) or not ((0 <= self.episode_map) & (self.episode_map < self.map_stack.num_maps)).all():
            raise ValueError(f"episode_map: expected {n_episodes} map numbers from 0 to {self.map_stack.num_maps - 1}, got {episode_map!r}")
        road_map = self.map_stack.combined
        missions, episode_of = [], []
        for b, group in enumerate(episode_missions):
            if not group:
                raise ValueError(f"episode {b}: no agents")
            for m in group:
                missions.append(dataclasses.replace(m, agent_id=f"{b}/{m.agent_id}"))
                episode_of.append(b)
        self.episodes = n_episodes
        self.episode_capacity = int(capacity)
        super().__init__(road_map, missions, providers, dt=dt, episode_steps=max(episode_steps),
                         events=events, capacity=n_episodes * self.episode_capacity, seed=int(seeds[0]))  # fmt: skip
        self.local_agent_ids = [m.agent_id for group in episode_missions for m in group]
        self.agent_episode = np.array(episode_of, dtype=np.int64)
        counts = np.bincount(self.agent_episode, minlength=n_episodes)
        self.episode_agent_start = np.concatenate([[0], np.cumsum(counts)]).astype(np.int64)
        self.episode_limit = np.asarray(episode_steps, dtype=np.int64)
        self.episode_step = np.zeros(n_episodes, dtype=np.int64)
        self.episode_time = np.zeros(n_episodes)
        self.episode_seed = [check_seed(s, f"episode {b} seed") for b, s in enumerate(seeds)]
        self.lead_ids = [(int(b), m.follow) if m.follow else None for b, m in zip(episode_of, missions)]
        self.table.row_of = _EpisodeRows(self)
        self.via_colour = np.zeros((n_episodes, road_map.num_lanes), dtype=np.int8)
        signals = list(signals) if signals is not None else [None] * n_episodes
        for b, state in enumerate(signals):
            if state is not None:  # the signals now write into the batch's colour block
                self.via_colour[b] = state.via_colour
                state.via_colour = self.via_colour[b]
        cap = self.episode_capacity
        self.views = [
            EpisodeView(block_view(self.table, b * cap, (b + 1) * cap), self.map_stack.windows[self.episode_map[b]],
                        self.dt, self.episode_seed[b], signals[b])  # fmt: skip
            for b in range(n_episodes)
        ]
        self.row_map = np.repeat(self.episode_map, cap)  # map of every stacked row
        self.episode_providers = [list(p) for p in episode_providers]
        for provs in self.episode_providers:
            for k, p in enumerate(provs):
                p.provider_id = len(self.providers) + k  # as in a single simulation of the episode
        self.action_array: np.ndarray | None = None
        self._all_episodes = np.arange(n_episodes, dtype=np.int64)
        self.batch_stages: list = []
        self._stepped = [list(p) for p in self.episode_providers]  # stepped one episode at a time

    def add_batch_stage(self, stage) -> None:
        """Let ``stage`` step some episode providers of all episodes at once: ``stage.steps(p)``
        says which, ``stage.step(sim, dt)`` runs after the per-episode providers and
        ``stage.after_reset(sim, episodes)`` after episodes are reset."""
        self.batch_stages.append(stage)
        self._stepped = [[p for p in provs if not stage.steps(p)] for provs in self._stepped]

    # ------------------------------------------------------------------ episodes
    def episode_agents(self, b: int) -> np.ndarray:
        return np.arange(self.episode_agent_start[b], self.episode_agent_start[b + 1], dtype=np.int64)

    def reset(self, seed: int | None = None) -> None:
        """Reset every episode (seeds ``seed + b``, or each episode's last seed)."""
        seeds = None if seed is None else [derived_seed(seed, b) for b in range(self.episodes)]
        self.reset_episodes(self._all_episodes, seeds)

    def reset_episodes(self, episodes: np.ndarray, seeds: Sequence[int | None] | None = None) -> None:
        """Start new episodes ``episodes`` (with ``seeds``; None keeps an episode's last seed)
        while the others keep their state."""
        episodes = np.asarray(episodes, dtype=np.int64)
        rows = []
        for k, b in enumerate(episodes.tolist()):
            view = self.views[b]
            if seeds is not None and seeds[k] is not None:
                self.episode_seed[b] = check_seed(seeds[k], f"episode {b} seed")
            view.seed = self.episode_seed[b]
            for p in self.episode_providers[b]:
                p.release(view, np.flatnonzero(view.table.alive))
            view.table.clear()
            view.time, view.step_count = 0.0, 0
            self.episode_step[b], self.episode_time[b] = 0, 0.0
            agents = self.episode_agents(b)
            self.agent_row[agents] = -1
            self.agent_active[agents] = False
            self.agent_events[agents] = False
            self.agent_done[agents] = False
            self.route_index[agents] = 0
            self.route_progress[agents] = 0.0
            self.route_progress_delta[agents] = 0.0
            self.agent_prev_row[agents] = -1
            for p in self.providers:
                p.reset_episode(self, b, agents)
            for p in self.episode_providers[b]:
                p.reset(view)
            for p in self.episode_providers[b]:
                p.start(view)
            missing = [self.agent_ids[a] for a in agents if self.agent_row[a] < 0]
            if missing:
                raise RuntimeError(f"no provider created a vehicle for agents {missing}")
            self.agent_active[agents] = True
            rows.append(np.flatnonzero(view.table.alive) + b * self.episode_capacity)
        self._refresh_active()
        for stage in self.batch_stages:
            stage.after_reset(self, episodes)
        rows = np.concatenate(rows) if rows else np.zeros(0, dtype=np.int64)
        self.not_moving.reset_rows(rows, self.table.x[rows], self.table.y[rows], 0.0)
        self.alive = self.table.alive_rows
        self._project(rows)
        agents = self._active[np.isin(self.agent_episode[self._active], episodes)]
        self._route_progress_of(agents, first=True)
        self._events_of(episodes)

    # ------------------------------------------------------------------ step
    def check_actions(self, actions: np.ndarray, agents: np.ndarray | None = None) -> None:
        for check in self._checks:
            check(self, actions, agents)

    def step(self, actions: np.ndarray) -> None:
        """Advance every episode by one step. ``actions[a]`` is union agent ``a``'s action (rows of
        agents not in an episode any more are ignored). Atomic: the actions of every active agent
        are checked first (``ActionError``, nothing moves)."""
        self.check_actions(actions)
        self.action_array = actions
        self.step_count += 1
        self.episode_step += 1
        self.episode_time = self.episode_step * self.dt  # per episode, as Simulation.time
        self.time = float(self.step_count * self.dt)
        for p in self.providers:
            p.step(self, self.dt)
        for b, provs in enumerate(self._stepped):
            if provs:
                view = self.views[b]
                view.step_count = int(self.episode_step[b])
                view.time = float(self.episode_time[b])
                for p in provs:
                    p.step(view, self.dt)
        for stage in self.batch_stages:
            stage.step(self, self.dt)
        self.alive = self.table.alive_rows
        self._project(self.alive)
        self._route_progress_of(self._active, first=False)
        self._events_of(self._all_episodes)

    def remove_done_agents(self) -> np.ndarray:
        """Remove the vehicles of agents that finished this step; returns their agent indices."""
        finished = np.flatnonzero(self.agent_active & self.agent_done)
        if finished.size:
            cap = self.episode_capacity
            for a in finished.tolist():
                b, row = int(self.agent_episode[a]), int(self.agent_row[a])
                for p in self.providers:
                    p.release(self, np.array([row]))
                self.views[b].table.remove(row - b * cap)
            self.agent_active[finished] = False
            self._refresh_active()
        return finished

    def episodes_over(self) -> np.ndarray:
        """Episodes none of whose agents is still active."""
        live = np.bincount(self.agent_episode[self._active], minlength=self.episodes)
        return np.flatnonzero(live == 0)

    def close(self) -> None:
        super().close()
        for provs in self.episode_providers:
            for p in provs:
                p.close()

    # ------------------------------------------------------------------ stages over the batch
    def episode_ranges(self, sorted_rows: np.ndarray, sorted_agents: np.ndarray) -> tuple[np.ndarray, ...]:
        """Per episode, ``[lo, hi)`` into ``sorted_rows`` (stacked rows) and into ``sorted_agents``
        (union agent indices), both ascending: the episode's share of each."""
        bounds = np.arange(self.episodes + 1, dtype=np.int64)
        row_cut = np.searchsorted(sorted_rows, bounds * self.episode_capacity)
        agent_cut = np.searchsorted(sorted_agents, self.episode_agent_start)
        return row_cut[:-1], row_cut[1:], agent_cut[:-1], agent_cut[1:]

    def project_rows(self, rows: np.ndarray):
        """``LaneProjection`` of stacked ``rows``, each on its episode's map (stacked lanes)."""
        t = self.table
        return self.map_stack.project(gather_xy(t, rows), t.heading[rows], self.row_map[rows])

    def _project(self, rows: np.ndarray) -> None:
        if rows.size == 0:
            return
        t = self.table
        proj = self.project_rows(rows)
        t.lane[rows] = proj.lane
        t.s[rows], t.t[rows], t.lane_heading[rows], t.lane_distance[rows] = (
            proj.s, proj.t, proj.lane_heading, proj.distance
        )

    def _route_progress_of(self, agents: np.ndarray, first: bool) -> None:
        self.route_progress_delta[agents] = 0.0
        ma = self.mission_arrays
        _route_progress(
            self.table.data, agents, self.agent_row[agents], ma.flat_paths, ma.stride, ma.path_len,
            ma.path_s, ma.route_length, self.route_index, self.route_progress,
            self.route_progress_delta, first,
        )

    def _events_of(self, episodes: np.ndarray) -> None:
        ma, st = self.mission_arrays, self.map_stack
        self.agent_events[~self.agent_active] = False
        agents = self._active
        alive_lo, alive_hi, agent_lo, agent_hi = self.episode_ranges(self.alive, agents)
        _episode_events(
            episodes, alive_lo, alive_hi, agent_lo, agent_hi,
            self.table.data, self.table.lane, self.alive, agents, self.agent_row[agents], self.episode_map,
            st.raster_flat, st.raster_base, st.raster_width, st.raster_origin, st.raster_inv_res, st.raster_cell_max,
            self.road_map.lane_internal, self.road_map.lane_road, ma.on_route_road,
            ma.goal_kind, ma.goal_xy, ma.goal_radius, ma.goal_road, ma.goal_lane, ma.goal_s,
            ma.goal_gate, self.agent_prev_xy, self.agent_prev_row,
            self.not_moving.anchor, self.not_moving.anchor_time,
            self.not_moving.seconds, self.not_moving.distance, self.episode_time,
            self.episode_step >= self.episode_limit, self.event_config.terminate_on,
            self.agent_events, self.agent_done,
        )  # fmt: skip


@numba.njit(cache=True, nogil=True)
def _episode_events(
    episodes, alive_lo, alive_hi, agent_lo, agent_hi,
    data, lane, alive, agents, rows, episode_map, raster_flat, raster_base, raster_width, raster_origin,
    raster_inv_res, raster_cell_max,
    lane_internal, lane_road, on_route_road, goal_kind, goal_xy, goal_radius, goal_road, goal_lane,
    goal_s, goal_gate, prev_xy, prev_row, anchor, anchor_time, not_moving_seconds,
    not_moving_distance, episode_time, at_step_limit, terminate_on, events, done,
):  # pragma: no cover - compiled
    """``agent_events`` of each episode in ``episodes`` with only that episode's rows as others,
    on its map's drivable raster (rasters concatenated, map ``m``'s from ``raster_base[m]``)."""
    for k in range(episodes.shape[0]):
        b = episodes[k]
        lo, hi = agent_lo[b], agent_hi[b]
        if lo == hi:
            continue
        m = episode_map[b]
        agent_events(
            data, lane, alive[alive_lo[b]:alive_hi[b]], agents[lo:hi], rows[lo:hi],
            raster_flat[raster_base[m]:raster_base[m + 1]], raster_width[m], raster_origin[m],
            raster_inv_res[m], raster_cell_max[m],
            lane_internal, lane_road, on_route_road, goal_kind, goal_xy, goal_radius, goal_road,
            goal_lane, goal_s, goal_gate, prev_xy, prev_row, anchor, anchor_time, not_moving_seconds,
            not_moving_distance, episode_time[b], at_step_limit[b], terminate_on, events, done,
        )  # fmt: skip


