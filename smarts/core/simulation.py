"""The step loop over B episodes: one vehicle table, one call per stage, B = 1 a single episode.

The episodes' vehicles live in one ``VehicleTable`` of ``B * capacity`` rows: episode ``b`` owns
rows ``b * capacity`` to ``(b + 1) * capacity`` (its *block*; ``row // capacity`` is the episode).
Agents are stacked the same way: agent ``a`` belongs to episode ``agent_episode[a]`` and the agents
of one episode are consecutive. With B = 1 the block is the whole table and everything is exactly
a single simulation, so there is one step for one episode or thousands.

Step order: clock += dt per episode; actions -> the agent provider (every agent of every episode in
one call per action space); each episode's own providers (replay, signals, SUMO) on its
``EpisodeView``; batch stages (one call for a kind of episode provider across all episodes, e.g.
the built-in traffic); map projection of every live row; route progress of every agent; events,
the pair tests (collisions) restricted to each agent's own episode. Observations and rewards are
built from this state by ``smarts.sensors`` and ``smarts.env``.

Providers come in two kinds (``smarts.core.provider``): *batch providers* (the agent provider)
step every episode's rows with global row numbers; *episode providers* belong to one episode and
see it as a single simulation through an ``EpisodeView`` (its block of the table as a
``VehicleTable`` of ``capacity`` rows, its clock, seed, map, signals and agents), so they run
unchanged whatever B is. Ownership is the ``owner`` column: provider ids are the batch
providers' first, then the episode's own, as in a single simulation of the episode.

Each episode keeps its own clock, step count, seed, step limit and event rules and is reset on its
own (``reset_episodes``) while the others go on; episode ``b`` reset with seed ``s`` follows the
same trajectory as a single simulation reset with seed ``s`` given the same actions. Episodes may
run on different maps: the maps are stacked into one lane index space (``smarts.maps.stack``) and
the two spatial lookups (lane projection, the drivable raster) take each row's map.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np

from smarts.core.events import NUM_EVENTS, Event, NotMovingTracker, agent_events, events_by_episode
from smarts.core.missions import MissionArrays, ResolvedMission, stack_missions
from smarts.core.provider import Provider, ProviderBase
from smarts.core.settle import ROUTE_WINDOW_AHEAD, ROUTE_WINDOW_BACK, advance_clocks, route_progress, settle  # noqa: F401
from smarts.core.sim_records import sim_tables
from smarts.core.vehicle_table import Role, VehicleTable
from smarts.maps import RoadMap, project
from smarts.maps.projection import Grids, projection_index
from smarts.maps.stack import MapStack, stack_maps

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


class Scope(NamedTuple):
    """What each of some agents may see: live rows ``alive[lo[i]:hi[i]]`` (its own episode's, global
    rows, ascending) and ``base[i]``, its episode's first row (local row = global - base)."""

    alive: np.ndarray
    lo: np.ndarray
    hi: np.ndarray
    base: np.ndarray


@dataclass
class EventConfig:
    terminate_on: np.ndarray  # bool[NUM_EVENTS]
    not_moving_seconds: float = 60.0
    not_moving_distance: float = 1.0


@dataclass
class EpisodeSetup:
    """One episode of a simulation: its agents' missions, its own providers (in stepping order,
    after the agent provider), its map (index into the simulation's map stack), step limit, event
    rules, seed and signal state (None on a map without signals)."""

    missions: list[ResolvedMission]
    providers: list[Provider] = dataclasses.field(default_factory=list)
    map_index: int = 0
    episode_steps: int = 1000
    events: EventConfig | None = None
    seed: int = 42
    signals: object = None


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


class EpisodeView:
    """Episode ``b`` as a single simulation, for the providers that belong to it: its block of the
    table (local rows), map, clock, seed, signals, its agents' missions and rows, and hand-overs in
    local rows. With B = 1 the table is the simulation's own."""

    def __init__(self, sim: "Simulation", b: int, table: VehicleTable, road_map: RoadMap, signals):
        self._sim = sim
        self.episode = b
        self.base = b * sim.episode_capacity
        self.table = table
        self.road_map = road_map
        self.signals = signals
        self.dt = sim.dt
        self.agents = np.arange(sim.episode_agent_start[b], sim.episode_agent_start[b + 1], dtype=np.int64)
        """This episode's agents as the simulation's agent indices."""
        self.missions = [sim.missions[a] for a in self.agents.tolist()]
        self.agent_ids = [sim.local_agent_ids[a] for a in self.agents.tolist()]

    @property
    def time(self) -> float:
        return float(self._sim.episode_time[self.episode])

    @property
    def step_count(self) -> int:
        return int(self._sim.episode_step[self.episode])

    @property
    def seed(self) -> int:
        return self._sim.episode_seed[self.episode]

    @property
    def agent_row(self) -> np.ndarray:
        """Local row of each of the episode's agents (-1: none)."""
        rows = self._sim.agent_row[self.agents]
        return np.where(rows >= 0, rows - self.base, -1)

    @property
    def active_agents(self) -> np.ndarray:
        """The episode's agents still in it, by their index within the episode."""
        return np.flatnonzero(self._sim.agent_active[self.agents])

    @property
    def active_rows(self) -> np.ndarray:
        """Local rows of the episode's agents still in the episode."""
        sim = self._sim
        active = self.agents[sim.agent_active[self.agents]]
        return sim.agent_row[active] - self.base

    def hand_over(self, rows: np.ndarray, to: Provider, role=None) -> None:
        self._sim.hand_over(np.asarray(rows, dtype=np.int64) + self.base, to, role)


class _EpisodeRows:
    """``table.row_of`` of a table of B > 1 episodes: keys are ``(episode, vehicle id)`` (the form
    of ``Simulation.lead_ids``), values the global row; ids live in the episode views."""

    def __init__(self, sim: "Simulation"):
        self.sim = sim

    def get(self, key, default=None):
        b, vid = key
        row = self.sim.views[b].table.row_of.get(vid)
        return default if row is None else row + b * self.sim.episode_capacity

    def __contains__(self, key) -> bool:
        return self.get(key) is not None

    def __len__(self) -> int:
        return sum(len(v.table.row_of) for v in self.sim.views)


class _StackedIds:
    """``table.ids`` of a table of B > 1 episodes: the id of global row ``r`` (from its episode's view)."""

    def __init__(self, sim: "Simulation"):
        self.sim = sim

    def __getitem__(self, row):
        cap = self.sim.episode_capacity
        row = int(row)
        return self.sim.views[row // cap].table.ids[row % cap]

    def __len__(self) -> int:
        return self.sim.table.capacity


class _OffsetRows:
    """An episode's id -> row map in global rows."""

    def __init__(self, rows: dict, offset: int):
        self.rows, self.offset = rows, offset

    def get(self, vid, default=None):
        row = self.rows.get(vid)
        return default if row is None else row + self.offset

    def __getitem__(self, vid):
        return self.rows[vid] + self.offset

    def __contains__(self, vid) -> bool:
        return vid in self.rows

    def __len__(self) -> int:
        return len(self.rows)


class _EpisodeTable:
    """The whole table with episode ``b``'s ids (rows are global rows)."""

    def __init__(self, sim: "Simulation", b: int):
        self._table = sim.table
        self.row_of = _OffsetRows(sim.views[b].table.row_of, b * sim.episode_capacity)

    def __getattr__(self, name: str):
        return getattr(self._table, name)


class EpisodeSim:
    """Episode ``b`` of a simulation as a single one, for per-episode readers (the benchmark's
    ``EpisodeRecorder``, the viewer's capture): its clock, its agents by their own ids
    (``agent_index`` maps them to the simulation's agent indices), their leads by vehicle id, and
    the global arrays. Everything else is the simulation's."""

    def __init__(self, sim: "Simulation", b: int):
        self._sim, self._b = sim, b
        agents = sim.views[b].agents.tolist()
        self.agent_index = {sim.local_agent_ids[a]: a for a in agents}
        self.lead_ids = [m.follow for m in sim.missions]
        self.table = _EpisodeTable(sim, b) if sim.episodes > 1 else sim.table
        self.road_map = sim.views[b].road_map  # its map, in the simulation's lane indices
        self.signals = sim.views[b].signals

    @property
    def time(self) -> float:
        return float(self._sim.episode_time[self._b])

    @property
    def step_count(self) -> int:
        return int(self._sim.episode_step[self._b])

    def __getattr__(self, name: str):
        return getattr(self._sim, name)


class Simulation:
    """``B`` episodes (``len(episodes)``) of scenarios as one simulation of all their agents.

    ``road_map``: the map of every episode, or a ``MapStack`` of several with
    ``episodes[b].map_index`` the map of episode ``b`` (missions and episode providers then use the
    stack's windows and stacked lane indices; ``self.road_map`` is the stack's combined map).
    ``providers``: the batch providers (the agent provider), stepping every episode's rows.
    ``step`` takes the actions of all agents: a dict by agent id, or an array ``[agents, k]``
    (each action space's agents read their first columns). With B > 1 the agents' ids are
    ``"<b>/<agent id>"``; ``local_agent_ids`` holds the scenarios' own. An episode whose agents
    have all finished keeps stepping its own providers (its traffic drives on) until
    ``reset_episodes`` starts it again.
    """

    def __init__(
        self,
        road_map: RoadMap | MapStack,
        episodes: Sequence[EpisodeSetup],
        providers: list[Provider],
        *,
        dt: float = 0.1,
        capacity: int = 256,
    ):
        n = len(episodes)
        if n == 0:
            raise ValueError("Simulation needs at least one episode")
        self.map_stack = road_map if isinstance(road_map, MapStack) else stack_maps([road_map])
        self.road_map = self.map_stack.combined
        self.episode_map = np.array([e.map_index for e in episodes], dtype=np.int64)
        if not ((0 <= self.episode_map) & (self.episode_map < self.map_stack.num_maps)).all():
            raise ValueError(
                f"episodes: map_index must be from 0 to {self.map_stack.num_maps - 1}, got {self.episode_map.tolist()}"
            )
        self.dt = float(dt)
        self.episodes = n
        self.episode_capacity = int(capacity)
        self.table = VehicleTable(n * self.episode_capacity)
        self._init_agents(episodes)
        self._init_events(episodes)
        self._init_episodes(episodes)
        self._init_views(episodes)
        self._init_providers(providers, episodes)
        self.actions: dict | np.ndarray = {}
        self.alive = np.zeros(0, dtype=np.int64)  # live rows after the last map update
        self._all_episodes = np.arange(n, dtype=np.int64)
        self._zero1 = np.zeros(1, dtype=np.int64)
        self._scope_zero = np.zeros(0, np.int64)
        self._scope_hi = np.zeros(0, np.int64)
        self._active = np.zeros(0, dtype=np.int64)
        self._active_rows = np.zeros(0, dtype=np.int64)

    def _init_agents(self, episodes: Sequence[EpisodeSetup]) -> None:
        """Every episode's missions as one agent list (ids prefixed by episode when B > 1), and per-agent state."""
        n = len(episodes)
        missions, episode_of = [], []
        for b, setup in enumerate(episodes):
            if not setup.missions:
                raise ValueError(f"episode {b}: no agents")
            for m in setup.missions:
                missions.append(m if n == 1 else dataclasses.replace(m, agent_id=f"{b}/{m.agent_id}"))
                episode_of.append(b)
        self.missions = missions
        self.local_agent_ids = [m.agent_id for setup in episodes for m in setup.missions]
        self.mission_arrays: MissionArrays = stack_missions(self.road_map, missions)
        self.agent_ids: list[str] = [m.agent_id for m in missions]
        self.agent_index = {a: i for i, a in enumerate(self.agent_ids)}
        self.agent_episode = np.array(episode_of, dtype=np.int64)
        counts = np.bincount(self.agent_episode, minlength=n)
        self.episode_agent_start = np.concatenate([[0], np.cumsum(counts)]).astype(np.int64)
        self.lead_ids: list = [
            (m.follow if n == 1 else (int(b), m.follow)) if m.follow else None for b, m in zip(episode_of, missions)
        ]
        """Per agent, the vehicle it follows (``smarts.core.following``): its id (B = 1) or
        ``(episode, id)``, the key of ``table.row_of``; None when it follows none."""
        self.hands_back = np.array([m.on_end == "traffic" for m in missions], dtype=bool)
        na = len(missions)
        self.agent_row = np.full(na, -1, dtype=np.int64)
        self.agent_active = np.zeros(na, dtype=bool)
        self.agent_events = np.zeros((na, NUM_EVENTS), dtype=bool)
        self.agent_done = np.zeros(na, dtype=bool)
        self.route_index = np.zeros(na, dtype=np.int64)  # nearest route point
        self.route_progress = np.zeros(na)  # arc length along the route path
        self.route_progress_delta = np.zeros(na)
        # where each agent's vehicle (row) was at the last event test: goals are tested on the
        # movement since then (a short goal lane can lie wholly inside one step's travel)
        self.agent_prev_xy = np.zeros((na, 2))
        self.agent_prev_row = np.full(na, -1, dtype=np.int64)

    def _init_events(self, episodes: Sequence[EpisodeSetup]) -> None:
        """Per-episode event settings: which events end an agent, and the not-moving test."""
        n = len(episodes)
        self.event_configs = [e.events or EventConfig(terminate_on=_default_terminations()) for e in episodes]
        self.terminate_on = np.array([c.terminate_on for c in self.event_configs], dtype=bool).reshape(n, NUM_EVENTS)
        self.not_moving_seconds = np.array([c.not_moving_seconds for c in self.event_configs], dtype=np.float64)
        self.not_moving_distance = np.array([c.not_moving_distance for c in self.event_configs], dtype=np.float64)
        first = self.event_configs[0]
        self.not_moving = NotMovingTracker(self.table.capacity, first.not_moving_seconds, first.not_moving_distance)

    def _init_episodes(self, episodes: Sequence[EpisodeSetup]) -> None:
        """Per-episode clocks and seeds; episodes with signals write their colours into one block."""
        n = len(episodes)
        self.episode_limit = np.array([e.episode_steps for e in episodes], dtype=np.int64)
        self.episode_step = np.zeros(n, dtype=np.int64)
        self.episode_time = np.zeros(n)
        self.episode_seed = [check_seed(e.seed, f"episode {b} seed") for b, e in enumerate(episodes)]
        self.via_colour = np.zeros((n, self.road_map.num_lanes), dtype=np.int8)
        for b, setup in enumerate(episodes):
            if setup.signals is not None:  # the signals now write into the simulation's colour block
                self.via_colour[b] = setup.signals.via_colour
                setup.signals.via_colour = self.via_colour[b]

    def _init_views(self, episodes: Sequence[EpisodeSetup]) -> None:
        """One view per episode onto its block of table rows and its map window."""
        n = len(episodes)
        if n > 1:
            self.table.row_of = _EpisodeRows(self)
            self.table.ids = _StackedIds(self)
        cap = self.episode_capacity
        self.views = [
            EpisodeView(
                self,
                b,
                self.table if n == 1 else block_view(self.table, b * cap, (b + 1) * cap),
                self.map_stack.windows[self.episode_map[b]],
                setup.signals,
            )  # fmt: skip
            for b, setup in enumerate(episodes)
        ]
        self.row_map = np.repeat(self.episode_map, cap)  # map of every row

    def _init_providers(self, providers: list[Provider], episodes: Sequence[EpisodeSetup]) -> None:
        """Batch providers step all episodes; each episode's own providers are numbered after them."""
        n = len(episodes)
        self.batch_providers: list[Provider] = []
        self._checks: list = []  # batch providers' check_actions, called before every step
        for p in providers:
            self._add_batch_provider(p)
        self.episode_providers: list[list[Provider]] = [[] for _ in range(n)]
        self._provider_episode: dict[int, int] = {}
        for b, setup in enumerate(episodes):
            for p in setup.providers:
                self._add_episode_provider(b, p)
        self._refresh_stages()

    # ------------------------------------------------------------------ providers
    def _add_batch_provider(self, provider: Provider) -> None:
        provider.provider_id = len(self.batch_providers)
        self.batch_providers.append(provider)
        check = getattr(provider, "check_actions", None)  # optional part of the protocol
        if check is not None and getattr(type(provider), "check_actions", None) is not ProviderBase.check_actions:
            self._checks.append(check)

    def _add_episode_provider(self, b: int, provider: Provider) -> None:
        provider.provider_id = len(self.batch_providers) + len(self.episode_providers[b])
        self.episode_providers[b].append(provider)
        self._provider_episode[id(provider)] = b

    def add_provider(self, provider: Provider) -> None:
        """Add a provider to a single-episode simulation (stepped after the others)."""
        if self.episodes != 1:
            raise ValueError("add_provider: a simulation of several episodes is built with its providers")
        self._add_episode_provider(0, provider)
        self._refresh_stages()

    def providers_of(self, b: int) -> list[Provider]:
        """Episode ``b``'s providers by provider id: the batch providers, then its own."""
        return self.batch_providers + self.episode_providers[b]

    @property
    def providers(self) -> list[Provider]:
        """Episode 0's providers by provider id (with B = 1: every provider)."""
        return self.providers_of(0)

    def _refresh_stages(self) -> None:
        """One batch stage per kind of episode provider that has one (``batch_stage``): it steps
        that kind in every episode at once; the rest are stepped episode by episode."""
        kinds: dict[type, list] = {}
        for b, provs in enumerate(self.episode_providers):
            for p in provs:
                stage = getattr(p, "batch_stage", None)
                if stage is not None:
                    kinds.setdefault(stage, []).append((b, p))
        self.batch_stages = [stage(self, members) for stage, members in kinds.items()]
        stepped = {id(p) for members in kinds.values() for _, p in members}
        self._stepped = [[p for p in provs if id(p) not in stepped] for provs in self.episode_providers]

    def _owner(self, b: int, owner: int) -> Provider:
        nb = len(self.batch_providers)
        return self.batch_providers[owner] if owner < nb else self.episode_providers[b][owner - nb]

    def _call(self, provider: Provider, method: str, rows: np.ndarray):
        """``provider.<method>(sim or view, rows)`` in the provider's own row numbers."""
        b = self._provider_episode.get(id(provider))
        if b is None:
            return getattr(provider, method)(self, rows)
        base = b * self.episode_capacity
        if rows.size and not ((rows >= base) & (rows < base + self.episode_capacity)).all():
            raise ValueError(f"provider {provider.name!r} of episode {b} was given rows of another episode")
        return getattr(provider, method)(self.views[b], rows - base)

    def hand_over(self, rows: np.ndarray, to: Provider, role=None) -> None:
        """Move rows to another provider: the old owner releases them, the new one accepts them."""
        rows = np.asarray(rows, dtype=np.int64)
        ok = np.asarray(self._call(to, "can_accept", rows), dtype=bool)
        if not ok.all():
            raise ValueError(f"provider {to.name!r} cannot take vehicles {[self.table.ids[r] for r in rows[~ok]]}")
        self._release(rows)
        self.table.transfer(rows, to.provider_id, role)
        self._call(to, "accept", rows)

    def _release(self, rows: np.ndarray) -> None:
        """Each row's owner releases it (per episode, owners in id order)."""
        if rows.size == 0:
            return
        episode = rows // self.episode_capacity
        for b in np.unique(episode).tolist():
            mine = rows[episode == b]
            owners = self.table.owner[mine]
            for owner in np.unique(owners).tolist():
                if owner >= 0:
                    self._call(self._owner(b, owner), "release", mine[owners == owner])

    # ------------------------------------------------------------------ single-episode view
    @property
    def time(self) -> float:
        """Episode 0's clock (B = 1: the simulation's)."""
        return float(self.episode_time[0])

    @property
    def step_count(self) -> int:
        return int(self.episode_step[0])

    @property
    def seed(self) -> int:
        return self.episode_seed[0]

    @property
    def episode_steps(self) -> int:
        return int(self.episode_limit[0])

    @property
    def signals(self):
        return self.views[0].signals

    @property
    def event_config(self) -> EventConfig:
        return self.event_configs[0]

    def episode_sim(self, b: int) -> EpisodeSim:
        return EpisodeSim(self, b)

    def agent_step(self, agents: np.ndarray) -> np.ndarray:
        """The step count of each agent's episode."""
        return self.episode_step[self.agent_episode[agents]]

    # ------------------------------------------------------------------ episodes
    def episode_agents(self, b: int) -> np.ndarray:
        return self.views[b].agents

    def register_agent_vehicle(self, agent_id: str, row: int) -> None:
        self.agent_row[self.agent_index[agent_id]] = row

    def reset(self, seed: int | None = None) -> None:
        """Reset every episode (seeds ``seed + b``, or each episode's last seed)."""
        if seed is not None:
            seed = check_seed(seed, "Simulation.reset(seed=...)")
        seeds = None if seed is None else [derived_seed(seed, b) for b in range(self.episodes)]
        self.reset_episodes(self._all_episodes, seeds)

    def reset_episodes(self, episodes: np.ndarray, seeds: Sequence[int | None] | None = None) -> None:
        """Start new episodes ``episodes`` (with ``seeds``; None keeps an episode's last seed)
        while the others keep their state."""
        episodes = np.asarray(episodes, dtype=np.int64)
        rows = []
        self.actions = {}
        for k, b in enumerate(episodes.tolist()):
            view = self.views[b]
            if seeds is not None and seeds[k] is not None:
                self.episode_seed[b] = check_seed(seeds[k], f"episode {b} seed")
            alive = np.flatnonzero(view.table.alive) + view.base
            self._release(alive)
            view.table.clear()
            self.episode_step[b], self.episode_time[b] = 0, 0.0
            agents = view.agents
            self.agent_row[agents] = -1
            self.agent_active[agents] = False
            self.agent_events[agents] = False
            self.agent_done[agents] = False
            self.route_index[agents] = 0
            self.route_progress[agents] = 0.0
            self.route_progress_delta[agents] = 0.0
            self.agent_prev_row[agents] = -1
            for p in self.batch_providers:
                p.reset_episode(self, b, agents)
            for p in self.episode_providers[b]:
                p.reset(view)
            for p in self.batch_providers:
                p.start_episode(self, b, agents)
            for p in self.episode_providers[b]:
                p.start(view)
            missing = [self.agent_ids[a] for a in agents.tolist() if self.agent_row[a] < 0]
            if missing:
                raise RuntimeError(f"no provider created a vehicle for agents {missing}")
            self.agent_active[agents] = True
            rows.append(np.flatnonzero(view.table.alive) + view.base)
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
    def check_actions(self, actions, agents: np.ndarray | None = None) -> None:
        """Raise ``ActionError`` naming every agent whose action cannot be applied (missing, not
        real numbers, wrongly shaped, not finite), changing nothing. ``agents``: the agent indices
        to check (None: every active agent). ``step`` calls this before anything moves."""
        for check in self._checks:
            check(self, actions, agents)

    def step(self, actions) -> None:
        """Advance every episode by one step. ``actions``: by agent id, or an array whose row
        ``a`` is agent ``a``'s action (rows of agents not in an episode any more are ignored).

        Atomic: every action is checked first (``check_actions``); a refused step raises
        ``ActionError`` and changes nothing (no vehicle, controller, traffic, clock or step count).
        """
        self.check_actions(actions)
        self.actions = actions
        advance_clocks(self.episode_step, self.episode_time, self.dt)
        for p in self.batch_providers:
            p.step(self, self.dt)
        for b, provs in enumerate(self._stepped):
            if provs:
                view = self.views[b]
                for p in provs:
                    p.step(view, self.dt)
        for stage in self.batch_stages:
            stage.step(self, self.dt)
        self._settle()

    def _settle(self) -> None:
        """Live rows, map projection, route progress and events in one compiled call
        (``smarts.core.settle``)."""
        self.alive = settle(sim_tables(self), self._active, self.episode_time)

    def remove_done_agents(self) -> np.ndarray:
        """Remove the vehicles of agents that finished this step (or hand them to traffic, with
        ``on_end: traffic``); returns their agent indices."""
        if not self.agent_done.any():  # the usual step: nobody finished
            return np.zeros(0, dtype=np.int64)
        finished = np.flatnonzero(self.agent_active & self.agent_done)
        if finished.size:
            back = self.hands_back[finished]
            for a in finished[back].tolist():
                self._hand_back(a)
            rows = self.agent_row[finished[~back]]
            self._release(rows)
            cap = self.episode_capacity
            for row in rows.tolist():
                self.views[row // cap].table.remove(row % cap)
            self.agent_active[finished] = False
            self._refresh_active()
        return finished

    def _hand_back(self, agent: int) -> None:
        """Give a finished agent's vehicle to the first provider of its episode that takes it."""
        row = int(self.agent_row[agent])
        b = int(self.agent_episode[agent])
        owner = self.table.owner[row]
        for p in self.providers_of(b):
            if p.provider_id != owner and self._call(p, "can_accept", np.array([row]))[0]:
                self.hand_over(np.array([row]), p, Role.TRAFFIC)
                return
        raise RuntimeError(
            f"{self.table.ids[row]}: mission.on_end is 'traffic' but no traffic provider "
            "can take the vehicle (the scenario needs a traffic section)"
        )

    def episodes_over(self) -> np.ndarray:
        """Episodes none of whose agents is still active."""
        live = np.bincount(self.agent_episode[self._active], minlength=self.episodes)
        return np.flatnonzero(live == 0)

    def close(self) -> None:
        for p in self.batch_providers:
            p.close()
        for provs in self.episode_providers:
            for p in provs:
                p.close()

    # ------------------------------------------------------------------ per-step state
    @property
    def active_agents(self) -> np.ndarray:
        """Indices of the agents still in their episodes (cached; refreshed when agents leave)."""
        return self._active

    @property
    def active_rows(self) -> np.ndarray:
        """Table rows of ``active_agents``, in the same order."""
        return self._active_rows

    def _refresh_active(self) -> None:
        self._active = np.flatnonzero(self.agent_active)
        self._active_rows = self.agent_row[self._active]

    def episode_ranges(self, sorted_rows: np.ndarray, sorted_agents: np.ndarray) -> tuple[np.ndarray, ...]:
        """Per episode, ``[lo, hi)`` into ``sorted_rows`` (global rows) and into ``sorted_agents``
        (agent indices), both ascending: the episode's share of each."""
        if self.episodes == 1:
            return self._zero1, np.array([len(sorted_rows)]), self._zero1, np.array([len(sorted_agents)])
        bounds = np.arange(self.episodes + 1, dtype=np.int64)
        row_cut = np.searchsorted(sorted_rows, bounds * self.episode_capacity)
        agent_cut = np.searchsorted(sorted_agents, self.episode_agent_start)
        return row_cut[:-1], row_cut[1:], agent_cut[:-1], agent_cut[1:]

    def scope(self, agents: np.ndarray) -> Scope:
        """``Scope`` of ``agents``: each sees only the live rows of its own episode."""
        alive = self.alive
        if self.episodes == 1:  # everyone sees every live row (arrays kept between calls)
            n = len(agents)
            if len(self._scope_zero) < n:
                self._scope_zero = np.zeros(2 * n, np.int64)
                self._scope_hi = np.zeros(2 * n, np.int64)
            hi = self._scope_hi[:n]
            hi[:] = len(alive)
            return Scope(alive, self._scope_zero[:n], hi, self._scope_zero[:n])
        episode = self.agent_episode[agents]
        cap = self.episode_capacity
        lo = np.searchsorted(alive, episode * cap)
        hi = np.searchsorted(alive, (episode + 1) * cap)
        return Scope(alive, lo.astype(np.int64), hi.astype(np.int64), episode * cap)

    def update_map_state(self) -> None:
        """Project every live row onto its map again (lane, s, t), as after a step: for tools and
        tests that place vehicles by hand."""
        self.alive = self.table.alive_rows
        self._project(self.alive)

    @property
    def grids(self) -> Grids:
        """The projection grids of the simulation's maps (its one map's own, or the stack's)."""
        if self.map_stack.num_maps == 1:
            return projection_index(self.road_map).grids
        return self.map_stack.grids

    def project_rows(self, rows: np.ndarray):
        """``LaneProjection`` of ``rows``, each on its episode's map (stacked lanes)."""
        t = self.table
        if self.map_stack.num_maps == 1:  # one map: no map numbers to gather or check
            return project(self.road_map, gather_xy(t, rows), t.heading[rows])
        return self.map_stack.project(gather_xy(t, rows), t.heading[rows], self.row_map[rows])

    def _project(self, rows: np.ndarray) -> None:
        if rows.size == 0:
            return
        t = self.table
        proj = self.project_rows(rows)
        t.lane[rows] = proj.lane
        t.s[rows], t.t[rows], t.lane_heading[rows], t.lane_distance[rows] = (
            proj.s,
            proj.t,
            proj.lane_heading,
            proj.distance,
        )

    def _route_progress_of(self, agents: np.ndarray, first: bool) -> None:
        route_progress(sim_tables(self), agents, self.agent_row[agents], first)

    def _events_of(self, episodes: np.ndarray) -> None:
        self.agent_events[~self.agent_active] = False
        agents = self._active
        tables = sim_tables(self)
        if self.episodes == 1:  # the kernel itself: no episode ranges to cut
            if agents.size == 0:
                return
            agent_events(tables, self.alive, agents, self.agent_row[agents], 0, float(self.episode_time[0]))
            return
        alive_lo, alive_hi, agent_lo, agent_hi = self.episode_ranges(self.alive, agents)
        events_by_episode(
            tables, self.alive, agents, self.agent_row[agents], episodes, alive_lo, alive_hi, agent_lo, agent_hi,
            self.episode_time,
        )  # fmt: skip


def _default_terminations() -> np.ndarray:
    mask = np.zeros(NUM_EVENTS, dtype=bool)
    for e in (Event.COLLISION, Event.OFF_ROAD, Event.REACHED_GOAL, Event.MAX_STEPS):
        mask[e] = True
    return mask
