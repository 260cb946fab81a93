"""Record the per-step episode log that the benchmark metrics score.

The simulation side of the metric contract (``smarts.benchmark.metrics.log``): build an
``EpisodeRecorder`` right after ``reset`` (it keeps the reset state: the initial route distance,
the previous lateral acceleration for the first lateral jerk, the start pose), then call
``record`` after every step; it appends one row per mission agent from the simulation's arrays
(no per-vehicle Python work beyond the agents). Row ``k`` is the state after step ``k+1``: the
reset state is never a row, and no row is written past the scenario's time limit. ``finish``
returns an ``EpisodeLog``. Scoring never touches the simulator, so logs written here can be
re-scored later.

Route distance to the goal: along the mission's route path to the goal (for a road goal, its
offset on the goal lane, not the end of that lane), plus the lateral distance to the path. In
following tasks the goal is where the lead vehicle is when the episode ends, so those distances
(and the initial one, from the reset pose) are filled in at ``finish`` along the lane route from
the agent's start to the lead's final lane.

Following columns: from ``smarts.core.following.lead_state``, the one lead definition of the
project. The lead is "in lane and visible" when it is ahead on the follower's lane or on a lane
reached from it through successor lanes (lane continuity: a lead straight ahead stays in lane
across road-segment boundaries), within sight; the gap is bumper to bumper along those lanes.

Rule columns. ``red_light``: on this row the agent's vehicle entered, from a road lane (across
the stop line), a junction lane (the first lane of a signal-controlled connection,
``SignalState.via_colour``) whose colour was red at that moment. ``left_map``: the end-of-map rule (see ``smarts.benchmark.metrics.scores``): once the
front of an agent's vehicle passes the end of a lane of its route that has no successor (the
map's edge), within the lane's width, the vehicle has left the map; its trace ends on the row
before, which is marked ``left_map``, and what the events say from then on (partial off road,
then off road) is not recorded. The events kernel does not know this rule yet: the env still
ends such an agent with ``off_road`` a step or two later.

The scene (``EpisodeLog.scene``): at every row time, every other road user (leads, social
agents, traffic, replay, pedestrians) within ``SCENE_RADIUS`` of a live agent or a lead, and the
colours of the map's signals, so the viewer and the report's plots show the whole episode.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from smarts.benchmark.metrics.log import SCENE_RADIUS, TIME_LIMIT_TOLERANCE, AgentTrace, EpisodeLog, SceneTrace
from smarts.benchmark.metrics.params import MetricParams
from smarts.benchmark.metrics.scores import time_gap_to_margin
from smarts.compiled import njit
from smarts.core.errors import MapError
from smarts.core.events import Event
from smarts.core.following import LEAD_SIGHT, lead_rows, lead_state
from smarts.core.missions import GOAL_ROAD
from smarts.core.simulation import Simulation
from smarts.maps import project, route_polyline, shortest_route
from smarts.traffic.signals import RED

_COLUMNS = (
    "time", "x", "y", "heading", "speed", "accel_long", "accel_lat", "jerk_long", "jerk_lat",
    "lane_offset", "lane_width", "speed_limit", "route_distance_to_goal", "follow_time_gap",
)  # fmt: skip
_FLAGS = (
    "wrong_way", "partial_off_road", "off_road", "goal_reached", "in_follow_margin",
    "lead_in_lane_and_visible", "red_light", "left_map",
)  # fmt: skip
_LEFT_MAP = len(_COLUMNS) + _FLAGS.index("left_map")
_NO_SIGNALS = np.zeros(0, np.int8)


class EpisodeRecorder:
    """Collects the log of the learner agents of one episode; create it right after ``reset``.

    Leads come from the simulation (``sim.lead_ids``, set from each mission's ``follow``);
    ``follow`` (agent id -> lead vehicle id), when given, must agree with them. ``sight`` is how
    far a lead counts as visible (m). ``info`` is stored as the log's free-form ``info``.
    """

    def __init__(
        self,
        sim: Simulation,
        agent_ids: list[str],
        *,
        scenario: str,
        task: str,
        episode: int,
        seed: int,
        time_limit: float,
        follow: dict[str, str] | None = None,
        params: MetricParams | None = None,
        sight: float = LEAD_SIGHT,
        info: dict[str, Any] | None = None,
    ):
        self.sim = sim
        self.agent_ids = list(agent_ids)
        self.agents = np.array([sim.agent_index[a] for a in self.agent_ids], dtype=np.int64)
        self.meta = dict(scenario=scenario, task=task, episode=episode, seed=seed, time_limit=time_limit)
        self.follow = {a: sim.lead_ids[sim.agent_index[a]] for a in self.agent_ids if sim.lead_ids[sim.agent_index[a]]}
        if follow is not None and dict(follow) != self.follow:
            raise ValueError(
                f"follow {dict(follow)} disagrees with the missions' leads {self.follow} "
                "(a suite's follow is copied into each follower's mission.follow)"
            )
        self.params = params or MetricParams()
        self.sight = sight
        self.info = dict(info or {})
        self.rows: dict[str, list[np.ndarray]] = {a: [] for a in self.agent_ids}
        self._followers = np.array([sim.agent_index[a] for a in self.follow], dtype=np.int64)
        self._lead_xy = np.full((len(sim.agent_ids), 2), np.nan)  # per agent index: its lead, last seen
        self.failure: str | None = None
        self.start_time = float(sim.time)
        self.end_time: float | None = None
        self._goal_s = self._goal_along_route()
        # The reset state: kept, never written as a row.
        t = sim.table
        live = sim.agent_active[self.agents]
        rows = sim.agent_row[self.agents]
        self._prev_lat = np.full(len(sim.agent_ids), np.nan)
        self._prev_lat[self.agents[live]] = t.lat_accel[rows[live]]
        self._prev_lane = np.full(len(sim.agent_ids), -1, dtype=np.int64)
        self._prev_lane[self.agents[live]] = t.lane[rows[live]]
        self._gone = np.zeros(len(sim.agent_ids), dtype=bool)  # left the map at its route's end
        self._map_ends = self._route_map_ends()
        signals = getattr(sim, "signals", None)
        self._signals = signals if signals is not None and signals.has_signals else None
        self._scene_rows: list[tuple[float, np.ndarray, np.ndarray, np.ndarray]] = []
        self._scene_ids: dict[str, int] = {}
        self._scene_size: list[tuple[float, float, int]] = []
        self._row_serial: np.ndarray | None = None  # per table row: serial of the vehicle its scene index is of
        self._row_index: np.ndarray | None = None
        self._position = {int(a): k for k, a in enumerate(self.agents.tolist())}  # agent index -> position
        self.start_pose: dict[str, tuple[float, float, float]] = {}
        self.initial_route_distance: dict[str, float] = {}
        to_goal = self._route_distance(self.agents[live], rows[live])
        for k, a in enumerate(np.flatnonzero(live).tolist()):
            r = rows[a]
            agent_id = self.agent_ids[a]
            self.start_pose[agent_id] = (float(t.x[r]), float(t.y[r]), float(t.heading[r]))
            self.initial_route_distance[agent_id] = float(to_goal[k])
        self._note_leads()

    def _route_distance(self, agents: np.ndarray, rows: np.ndarray) -> np.ndarray:
        """Along the route to the goal plus the lateral distance to the matched route point."""
        sim, t = self.sim, self.sim.table
        point = sim.mission_arrays.paths[agents, sim.route_index[agents], 0]  # x, y, heading
        # Lateral (cross-track) distance to the matched route point's line; the along-track part
        # is already in the route progress.
        off_route = np.abs(
            -(t.x[rows] - point[:, 0]) * np.sin(point[:, 2]) + (t.y[rows] - point[:, 1]) * np.cos(point[:, 2])
        )
        return np.maximum(self._goal_s[agents] - sim.route_progress[agents], 0.0) + off_route

    def _goal_along_route(self) -> np.ndarray:
        """Per agent index: the route arc length of the goal. The route path of a road goal runs
        to the end of the goal lane; the goal is at the goal's offset on that lane, so the rest
        of the lane is not distance still to drive."""
        rm = self.sim.road_map
        out = np.array(self.sim.mission_arrays.route_length, dtype=np.float64)
        for a in self.agents.tolist():  # its own agents (one episode of a batch: not the others')
            m = self.sim.missions[a]
            if m.goal_kind == GOAL_ROAD and len(m.path_lane):
                beyond = float(rm.lane_length[int(m.path_lane[-1])]) - float(m.goal_s)
                out[a] = max(float(m.path_s[-1]) - max(beyond, 0.0), 0.0)
        return out

    def _route_map_ends(self) -> dict[int, frozenset[int]]:
        """Per agent index of its own agents: the lanes of its route without a successor (where
        the map stops)."""
        rm = self.sim.road_map
        out = {}
        for a in self.agents.tolist():
            lanes = {int(lane) for lane in np.unique(np.asarray(self.sim.missions[a].path_lane)) if lane >= 0}
            out[a] = frozenset(lane for lane in lanes if len(rm.successors(lane)) == 0)
        return out

    def _leaving_map(self, agents: np.ndarray, rows: np.ndarray) -> np.ndarray:
        """Per agent: its vehicle's front has passed the end of a route lane where the map stops,
        within the lane's width (on a later row it may be matched to no lane: the previous one
        counts)."""
        t, rm = self.sim.table, self.sim.road_map
        out = np.zeros(len(agents), dtype=bool)
        for k, (a, r) in enumerate(zip(agents.tolist(), rows.tolist())):
            ends = self._map_ends[a]
            if not ends:
                continue
            lane = int(t.lane[r]) if t.lane[r] >= 0 else int(self._prev_lane[a])
            if lane not in ends:
                continue
            if t.lane[r] < 0:  # off every lane straight after being on a map end: past it
                out[k] = True
                continue
            front = float(t.s[r]) + 0.5 * float(t.length[r])
            out[k] = front >= float(rm.lane_length[lane]) - 1e-6 and abs(float(t.t[r])) <= 0.5 * float(
                rm.lane_width[lane]
            )
        return out

    def _red_light(self, agents: np.ndarray, lanes: np.ndarray) -> np.ndarray:
        """Per agent: entered, on this step, from a road lane (across the stop line), a junction
        lane whose signal is red now. Moving on from one junction lane to the next is not
        entering the junction (a left turn's second junction lane can be another connection's
        first)."""
        if self._signals is None:
            return np.zeros(len(agents), dtype=bool)
        prev = self._prev_lane[agents]
        from_road = (prev < 0) | ~self.sim.road_map.lane_internal[np.maximum(prev, 0)]
        entered = (lanes >= 0) & (lanes != prev) & from_road
        colour = self._signals.via_colour[np.maximum(lanes, 0)]
        return entered & (colour == RED)

    def _record_scene(self) -> None:
        """One scene row: the other road users near the live agents and the leads, and the
        signal colours (the reset state is not a row)."""
        sim, t = self.sim, self.sim.table
        rows = np.asarray(t.alive_rows, dtype=np.int64)
        if sim.episodes > 1:  # one episode of a batch: its own block of the table
            rows = rows[rows // sim.episode_capacity == sim.agent_episode[self.agents[0]]]
        agent_rows = sim.agent_row[self.agents]
        mine = agent_rows[(agent_rows >= 0) & sim.agent_active[self.agents]]
        leads = [t.row_of.get(lead) for lead in self.follow.values()]
        leads = np.array([r for r in leads if r is not None], dtype=np.int64)
        others = rows[~np.isin(rows, agent_rows[agent_rows >= 0])]
        centres = np.concatenate([mine, leads])
        if centres.size and others.size:
            d2 = (t.x[others][:, None] - t.x[centres][None, :]) ** 2 + (
                t.y[others][:, None] - t.y[centres][None, :]
            ) ** 2
            near = (d2 <= SCENE_RADIUS**2).any(axis=1) | np.isin(others, leads)
            others = others[near]
        elif not centres.size:
            others = others[:0]
        index = self._scene_index(others)
        state = np.stack([t.x[others], t.y[others], t.heading[others], t.speed[others]], axis=1).astype(np.float32)
        self._scene_rows.append((float(sim.time - self.start_time), index, state, self._signal_colours()))

    def _scene_index(self, rows: np.ndarray) -> np.ndarray:
        """The scene index of the vehicle in each of ``rows`` (numbered as first seen; its size
        and role are noted then). A row still holding the vehicle it held (same serial) is not
        looked up by id again."""
        t = self.sim.table
        if self._row_serial is None:
            self._row_serial = np.zeros(len(t.serial), dtype=np.int64)
            self._row_index = np.zeros(len(t.serial), dtype=np.int32)
        serial = t.serial[rows]
        miss = self._row_serial[rows] != serial
        for r in rows[miss].tolist():
            self._row_index[r] = self._scene_id(r)
        self._row_serial[rows[miss]] = serial[miss]
        return self._row_index[rows]

    def _scene_id(self, row: int) -> int:
        """The scene index of the vehicle in ``row`` (a new one when first seen)."""
        t = self.sim.table
        vid = str(t.ids[row])
        i = self._scene_ids.get(vid)
        if i is None:
            i = self._scene_ids[vid] = len(self._scene_ids)
            self._scene_size.append((float(t.length[row]), float(t.width[row]), int(t.role[row])))
        return i

    def _signal_colours(self) -> np.ndarray:
        colours = self._signals.colour.astype(np.int8) if self._signals is not None else np.zeros(0, np.int8)
        return colours.copy()

    def scene(self) -> SceneTrace:
        """The scene recorded so far."""
        rows = self._scene_rows
        n_signals = len(self._signals.colour) if self._signals is not None else 0
        counts = [len(r[1]) for r in rows]
        state = np.concatenate([r[2] for r in rows]) if rows else np.zeros((0, 4), np.float32)
        size = np.array(self._scene_size, dtype=np.float64).reshape(-1, 3)
        return SceneTrace(
            time=np.array([r[0] for r in rows], dtype=np.float64),
            offsets=np.concatenate([[0], np.cumsum(counts, dtype=np.int64)]).astype(np.int64),
            index=np.concatenate([r[1] for r in rows]).astype(np.int32) if rows else np.zeros(0, np.int32),
            x=state[:, 0].copy(), y=state[:, 1].copy(), heading=state[:, 2].copy(), speed=state[:, 3].copy(),
            ids=list(self._scene_ids), length=size[:, 0].astype(np.float32), width=size[:, 1].astype(np.float32),
            role=size[:, 2].astype(np.int8),
            signals=np.array([r[3] for r in rows], dtype=np.int8).reshape(len(rows), n_signals),
            leads=dict(self.follow),
        )  # fmt: skip

    def _note_leads(self) -> None:
        """Where each follower's lead is now, while it is on the map."""
        note_leads(self.sim, self._followers, self._lead_xy)

    @property
    def lead_final(self) -> dict[str, tuple[float, float]]:
        """Follower agent id -> where its lead was last seen (x, y)."""
        xy = self._lead_xy[self._followers]
        return {a: (float(x), float(y)) for a, (x, y) in zip(self.follow, xy.tolist()) if not np.isnan(x)}

    def record(self) -> None:
        """Append the row of every agent still in the episode, for the step just taken.

        A call before any step (at the reset state) or after the time limit writes nothing."""
        sim, t, rm = self.sim, self.sim.table, self.sim.road_map
        if sim.time <= self.start_time + 1e-9:
            return  # the reset state is not a row
        if sim.time - self.start_time > self.meta["time_limit"] + TIME_LIMIT_TOLERANCE:
            return  # past the time limit: the episode is over for the metrics
        self.end_time = float(sim.time - self.start_time)
        self._record_scene()
        live = sim.agent_active[self.agents] & ~self._gone[self.agents]
        if live.any():
            leaving = self._leaving_map(self.agents[live], sim.agent_row[self.agents[live]])
            if leaving.any():  # the end-of-map rule: the last row inside the map ends the trace
                for a in self.agents[live][leaving].tolist():
                    self._gone[a] = True
                    mine = self.rows[self.agent_ids[int(np.flatnonzero(self.agents == a)[0])]]
                    if mine:
                        mine[-1][_LEFT_MAP] = 1.0
                live = sim.agent_active[self.agents] & ~self._gone[self.agents]
        if not live.any():
            self._note_leads()  # the scenario goes on: where the lead gets to is the followers' goal
            return
        agents = self.agents[live]
        rows = sim.agent_row[agents]
        lane = np.maximum(t.lane[rows], 0)
        speed = t.speed[rows]
        to_goal = self._route_distance(agents, rows)
        ev = sim.agent_events[agents]
        gap, in_margin, visible = self._follow_state(agents, speed)
        red = self._red_light(agents, t.lane[rows])
        self._prev_lane[agents] = np.where(t.lane[rows] >= 0, t.lane[rows], self._prev_lane[agents])
        values = np.stack(
            [
                np.full(len(agents), sim.time - self.start_time), t.x[rows], t.y[rows], t.heading[rows],
                speed, t.accel[rows], t.lat_accel[rows], t.jerk[rows], self._lat_jerk(agents, rows),
                t.t[rows], rm.lane_width[lane], rm.lane_speed_limit[lane], to_goal, gap,
                ev[:, Event.WRONG_WAY], ev[:, Event.PARTIAL_OFF_ROAD], ev[:, Event.OFF_ROAD],
                ev[:, Event.REACHED_GOAL], in_margin, visible, red, np.zeros(len(agents)),
            ],
            axis=1,
        )  # fmt: skip
        for k, a in enumerate(np.flatnonzero(live)):
            self.rows[self.agent_ids[a]].append(values[k])
        self._note_leads()

    def _lat_jerk(self, agents: np.ndarray, rows: np.ndarray) -> np.ndarray:
        """Lateral jerk by differencing lateral acceleration with the previous state (the reset
        state for the first row; 0 for an agent first seen on this row)."""
        lat = self.sim.table.lat_accel[rows]
        out = np.where(np.isnan(self._prev_lat[agents]), 0.0, (lat - self._prev_lat[agents]) / self.sim.dt)
        self._prev_lat[agents] = lat
        return out

    def _follow_state(self, agents: np.ndarray, speed: np.ndarray):
        """(time gap to the follow margin, inside the margin, lead in lane and visible) per agent."""
        n = len(agents)
        if not self.follow:
            return np.full(n, np.nan), np.zeros(n), np.zeros(n)
        lead = lead_state(self.sim, agents, self.sight)
        gap_s, inside = time_gap_to_margin(lead.gap, speed, self.params)
        in_lane = lead.in_lane
        gap = np.where(in_lane, gap_s, np.nan)
        return gap, (in_lane & inside).astype(np.float64), in_lane.astype(np.float64)

    def fail(self, reason: str) -> None:
        self.failure = reason

    def finish(self) -> EpisodeLog:
        traces = {}
        initial = {}
        for agent_id, rows in self.rows.items():
            if not rows:
                if self.failure is not None and agent_id in self.initial_route_distance:
                    traces[agent_id] = AgentTrace.empty(with_following=agent_id in self.follow)
                    initial[agent_id] = self.initial_route_distance[agent_id]
                continue
            data = np.array(rows)
            cols = {name: data[:, i] for i, name in enumerate(_COLUMNS)}
            flags = {name: data[:, len(_COLUMNS) + i] > 0.5 for i, name in enumerate(_FLAGS)}
            initial[agent_id] = self.initial_route_distance.get(agent_id, float(cols["route_distance_to_goal"][0]))
            if agent_id in self.follow:
                start = self.start_pose.get(agent_id, (cols["x"][0], cols["y"][0], cols["heading"][0]))
                xyh = np.concatenate([np.array([start]), np.stack([cols["x"], cols["y"], cols["heading"]], axis=1)])
                distance = self._distance_to_lead_end(agent_id, xyh)
                initial[agent_id] = float(distance[0])
                cols["route_distance_to_goal"] = distance[1:]
            traces[agent_id] = AgentTrace(**cols, **flags)
        sim = self.sim
        radii = [float(sim.mission_arrays.goal_radius[sim.agent_index[a]]) for a in traces]
        return EpisodeLog(
            **self.meta,
            dt=sim.dt,
            goal_radius=max(radii, default=0.0),
            initial_route_distance=initial,
            agents=traces,
            failure=self.failure,
            end_time=self.end_time,
            info=self.info,
            signals=0 if self._signals is None else int(len(self._signals.colour)),
            scene=self.scene(),
        )

    def _distance_to_lead_end(self, agent_id: str, xyh: np.ndarray) -> np.ndarray:
        """Route distance from each pose (x, y, heading; the start pose first) to where the lead
        was at the end."""
        rm = self.sim.road_map
        end = self.lead_final.get(agent_id)
        xy = xyh[:, :2]
        if end is None:
            return np.zeros(len(xy))
        start = project(rm, xy[:1], xyh[:1, 2])
        goal = project(rm, np.array([end]))
        try:
            route = shortest_route(rm, int(start.lane[0]), int(goal.lane[0]))
        except MapError:
            return np.hypot(*(xy - np.array(end)).T)
        path = route_polyline(rm, route, start_s=float(max(start.s[0], 0.0)))
        # Goal = the path point nearest the lead's final position.
        goal_i = int(np.argmin(np.hypot(*(path.xy - np.array(end)).T)))
        nearest, d2 = _nearest_points(
            np.ascontiguousarray(xy, dtype=np.float64), np.ascontiguousarray(path.xy[: goal_i + 1], dtype=np.float64)
        )
        return path.s[goal_i] - path.s[nearest] + np.sqrt(d2)


def note_leads(sim: Simulation, followers: np.ndarray, lead_xy: np.ndarray, rows: np.ndarray | None = None) -> None:
    """``lead_xy[a]`` = the position of follower ``a``'s lead, for each of ``followers`` (agent
    indices) whose lead is on the map now (one lookup for all of them: ``lead_rows``, or its
    ``rows`` when already looked up)."""
    if not len(followers):
        return
    rows = lead_rows(sim, followers) if rows is None else rows
    seen = rows >= 0
    t = sim.table
    lead_xy[followers[seen], 0] = t.x[rows[seen]]
    lead_xy[followers[seen], 1] = t.y[rows[seen]]


def _flags(size: int, rows: np.ndarray) -> np.ndarray:
    """A boolean mask over ``size`` table rows, True at ``rows`` (``np.isin`` against the rows,
    without its sort, for the per-step scene)."""
    mask = np.zeros(size, dtype=bool)
    mask[rows] = True
    return mask


def _member(values: np.ndarray, sorted_keys: np.ndarray) -> np.ndarray:
    """``np.isin(values, sorted_keys)`` for keys sorted ascending, by binary search."""
    if not len(sorted_keys):
        return np.zeros(len(values), dtype=bool)
    at = np.minimum(np.searchsorted(sorted_keys, values), len(sorted_keys) - 1)
    return sorted_keys[at] == values


@njit
def _nearest_points(xy: np.ndarray, path: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """For each point of ``xy``, the index of the nearest point of ``path`` (the first of equals)
    and its squared distance: the arithmetic of numpy's ``((a - b) ** 2).sum(axis=-1).argmin()``
    without its points x path temporary arrays (an episode's few hundred poses against a route's
    points, for every agent that follows a lead)."""
    n, m = len(xy), len(path)
    nearest = np.zeros(n, dtype=np.int64)
    best = np.empty(n)
    for i in range(n):
        x, y = xy[i, 0], xy[i, 1]
        low = np.inf
        k = 0
        for j in range(m):
            d = (x - path[j, 0]) ** 2 + (y - path[j, 1]) ** 2
            if d < low:
                low, k = d, j
        nearest[i], best[i] = k, low
    return nearest, best


class EpisodeRecorders:
    """The recorders of several episodes of one simulation (each on ``sim.episode_sim(b)``),
    recorded in one pass per step: :meth:`record` gives every recorder the rows its own
    ``record()`` would append, bit for bit (the same element-wise arithmetic on the same values,
    gathered over all their agents at once), so a batch of benchmark episodes costs a few array
    operations per step instead of a few dozen per episode. Their per-agent state arrays (indexed
    by the simulation's agent indices, each recorder touching only its own agents) are shared."""

    def __init__(self, sim: Simulation, recorders: list[EpisodeRecorder], episodes: list[int]):
        self.sim, self.recorders, self.episodes = sim, list(recorders), np.asarray(episodes, dtype=np.int64)
        first = self.recorders[0]
        for name in ("_prev_lat", "_prev_lane", "_gone", "_lead_xy"):
            shared = getattr(first, name)
            for r in self.recorders[1:]:
                shared[r.agents] = getattr(r, name)[r.agents]
                setattr(r, name, shared)
        self.prev_lat, self.prev_lane, self.gone = first._prev_lat, first._prev_lane, first._gone
        self.goal_s = np.zeros(len(sim.agent_ids))
        for r in self.recorders:
            self.goal_s[r.agents] = r._goal_s[r.agents]
        self.follows = [bool(r.follow) for r in self.recorders]
        self.followers = [r._followers for r in self.recorders]
        self.owner = {a: i for i, r in enumerate(self.recorders) for a in r.agents.tolist()}
        self.lanes = int(sim.road_map.num_lanes)
        self.end_keys = np.array(sorted(a * self.lanes + lane for r in self.recorders for a in r.agents.tolist()
                                        for lane in r._map_ends[a]), dtype=np.int64)  # fmt: skip
        """``agent * lanes + lane`` for every lane of an agent's route where the map stops."""
        self.row_serial = np.zeros(len(sim.table.serial), dtype=np.int64)  # as EpisodeRecorder._scene_index,
        self.row_index = np.zeros(len(sim.table.serial), dtype=np.int32)  # for every episode's rows at once
        self.same_rules = all(r.sight == first.sight and r.params == first.params for r in self.recorders)

    def record(self, which: list[int]) -> None:
        """``record()`` of ``self.recorders[i]`` for every ``i`` in ``which`` (ascending)."""
        sim = self.sim
        due = []
        for i in which:
            r = self.recorders[i]
            now = float(sim.episode_time[self.episodes[i]])
            if now <= r.start_time + 1e-9 or now - r.start_time > r.meta["time_limit"] + TIME_LIMIT_TOLERANCE:
                continue
            r.end_time = float(now - r.start_time)
            due.append(i)
        if not due:
            return
        followers = np.concatenate([self.followers[i] for i in due])
        leads = lead_rows(sim, followers) if len(followers) else followers
        self._scenes(due, leads[leads >= 0])
        live = self._leave_map(due)
        rows_of = [i for i in due if live[i].size]
        if rows_of:
            self._rows(rows_of, live)
        note_leads(sim, followers, self.recorders[0]._lead_xy, leads)

    def _leave_map(self, due: list[int]) -> dict[int, np.ndarray]:
        """Per due recorder, its live agents after the end-of-map rule (``_leaving_map`` of all
        of them at once)."""
        sim, t, rm = self.sim, self.sim.table, self.sim.road_map
        agents = [self.recorders[i].agents for i in due]
        everyone = np.concatenate(agents)
        live = sim.agent_active[everyone] & ~self.gone[everyone]
        cand = everyone[live]
        rows = sim.agent_row[cand]
        lane = np.where(t.lane[rows] >= 0, t.lane[rows], self.prev_lane[cand])
        at_end = (lane >= 0) & _member(cand * self.lanes + lane, self.end_keys)
        if at_end.any():
            a, r, lane, off = cand[at_end], rows[at_end], lane[at_end], t.lane[rows[at_end]] < 0
            front = t.s[r] + 0.5 * t.length[r]
            past = off | ((front >= rm.lane_length[lane] - 1e-6) & (np.abs(t.t[r]) <= 0.5 * rm.lane_width[lane]))
            for agent in a[past].tolist():
                self.gone[agent] = True
                rec = self.recorders[self.owner[agent]]
                mine = rec.rows[rec.agent_ids[rec._position[agent]]]
                if mine:
                    mine[-1][_LEFT_MAP] = 1.0
            live = sim.agent_active[everyone] & ~self.gone[everyone]
        cuts = np.cumsum([0] + [len(x) for x in agents])
        return {i: agents[k][live[cuts[k] : cuts[k + 1]]] for k, i in enumerate(due)}

    def _rows(self, which: list[int], live: dict[int, np.ndarray]) -> None:
        """One row per live agent of the recorders ``which``, computed for all of them at once."""
        sim, t, rm = self.sim, self.sim.table, self.sim.road_map
        agents = np.concatenate([live[i] for i in which])
        owner = np.repeat(np.arange(len(which)), [len(live[i]) for i in which])
        rows = sim.agent_row[agents]
        lane = np.maximum(t.lane[rows], 0)
        speed = t.speed[rows]
        point = sim.mission_arrays.paths[agents, sim.route_index[agents], 0]
        off_route = np.abs(
            -(t.x[rows] - point[:, 0]) * np.sin(point[:, 2]) + (t.y[rows] - point[:, 1]) * np.cos(point[:, 2])
        )
        to_goal = np.maximum(self.goal_s[agents] - sim.route_progress[agents], 0.0) + off_route
        ev = sim.agent_events[agents]
        gap, in_margin, visible = self._follow(which, agents, owner, speed)
        red = np.zeros(len(agents), dtype=bool)
        for k, i in enumerate(which):
            if self.recorders[i]._signals is not None:
                at = owner == k
                red[at] = self.recorders[i]._red_light(agents[at], t.lane[rows[at]])
        self.prev_lane[agents] = np.where(t.lane[rows] >= 0, t.lane[rows], self.prev_lane[agents])
        lat = t.lat_accel[rows]
        prev = self.prev_lat[agents]
        lat_jerk = np.where(np.isnan(prev), 0.0, (lat - prev) / sim.dt)
        self.prev_lat[agents] = lat
        starts = np.array([self.recorders[i].start_time for i in which])
        now = sim.episode_time[self.episodes[which]] - starts
        values = np.stack(
            [
                now[owner], t.x[rows], t.y[rows], t.heading[rows],
                speed, t.accel[rows], t.lat_accel[rows], t.jerk[rows], lat_jerk,
                t.t[rows], rm.lane_width[lane], rm.lane_speed_limit[lane], to_goal, gap,
                ev[:, Event.WRONG_WAY], ev[:, Event.PARTIAL_OFF_ROAD], ev[:, Event.OFF_ROAD],
                ev[:, Event.REACHED_GOAL], in_margin, visible, red, np.zeros(len(agents)),
            ],
            axis=1,
        )  # fmt: skip
        k = 0
        for i in which:
            r = self.recorders[i]
            for a in live[i].tolist():
                r.rows[r.agent_ids[r._position[a]]].append(values[k])
                k += 1

    def _follow(self, which: list[int], agents: np.ndarray, owner: np.ndarray, speed: np.ndarray):
        """The following columns of ``agents`` (as ``EpisodeRecorder._follow_state``)."""
        n = len(agents)
        gap, in_margin, visible = np.full(n, np.nan), np.zeros(n), np.zeros(n)
        following = np.array([self.follows[i] for i in which], dtype=bool)[owner]
        if not following.any():
            return gap, in_margin, visible
        if not self.same_rules:
            for k, i in enumerate(which):
                at = owner == k
                gap[at], in_margin[at], visible[at] = self.recorders[i]._follow_state(agents[at], speed[at])
            return gap, in_margin, visible
        r = self.recorders[which[0]]
        lead = lead_state(self.sim, agents[following], r.sight)
        gap_s, inside = time_gap_to_margin(lead.gap, speed[following], r.params)
        gap[following] = np.where(lead.in_lane, gap_s, np.nan)
        in_margin[following] = (lead.in_lane & inside).astype(np.float64)
        visible[following] = lead.in_lane.astype(np.float64)
        return gap, in_margin, visible

    def _scenes(self, due: list[int], leads: np.ndarray) -> None:
        """One scene row per due recorder (as ``EpisodeRecorder._record_scene``); ``leads``: the
        rows of their followers' leads on the map."""
        sim, t = self.sim, self.sim.table
        alive = np.asarray(t.alive_rows, dtype=np.int64)
        place = np.full(sim.episodes, -1, dtype=np.int64)
        place[self.episodes[due]] = np.arange(len(due))
        rows = alive[place[alive // sim.episode_capacity] >= 0]
        recs = [self.recorders[i] for i in due]
        all_agents = np.concatenate([r.agents for r in recs])
        agent_rows = sim.agent_row[all_agents]
        mine = agent_rows[(agent_rows >= 0) & sim.agent_active[all_agents]]
        others = rows[~_flags(len(t.serial), agent_rows[agent_rows >= 0])[rows]]
        centres = np.concatenate([mine, leads])
        c_owner = place[centres // sim.episode_capacity]
        order = np.argsort(c_owner, kind="stable")
        centres, c_owner = centres[order], c_owner[order]
        o_owner = place[others // sim.episode_capacity]
        is_lead = _flags(len(t.serial), leads)[others]
        near = self._near(others, o_owner, centres, c_owner, len(due)) | is_lead
        others, o_owner = others[near], o_owner[near]
        state = np.stack([t.x[others], t.y[others], t.heading[others], t.speed[others]], axis=1).astype(np.float32)
        serial = t.serial[others]
        miss = self.row_serial[others] != serial
        for row, k in zip(others[miss].tolist(), o_owner[miss].tolist()):
            self.row_index[row] = recs[k]._scene_id(row)
        self.row_serial[others[miss]] = serial[miss]
        index = self.row_index[others]
        cuts = np.searchsorted(o_owner, np.arange(len(due) + 1))
        times = sim.episode_time[self.episodes[due]].tolist()
        for k, r in enumerate(recs):
            colours = r._signal_colours() if r._signals is not None else _NO_SIGNALS
            r._scene_rows.append((float(times[k] - r.start_time), index[cuts[k] : cuts[k + 1]],
                                  state[cuts[k] : cuts[k + 1]], colours))  # fmt: skip

    def _near(
        self, others: np.ndarray, o_owner: np.ndarray, centres: np.ndarray, c_owner: np.ndarray, n: int
    ) -> np.ndarray:
        """Whether each of ``others`` is within ``SCENE_RADIUS`` of a centre of its own episode
        (both grouped by owner: only each episode's own pairs, with the distances its own
        recorder computes)."""
        if not len(others) or not len(centres):
            return np.zeros(len(others), dtype=bool)
        t = self.sim.table
        start = np.searchsorted(c_owner, np.arange(n))
        reps = np.bincount(c_owner, minlength=n)[o_owner]
        other = np.repeat(np.arange(len(others)), reps)
        offset = np.arange(len(other)) - np.repeat(np.cumsum(reps) - reps, reps)
        centre = centres[np.repeat(start[o_owner], reps) + offset]
        o = others[other]
        d2 = (t.x[o] - t.x[centre]) ** 2 + (t.y[o] - t.y[centre]) ** 2
        return np.bincount(other[d2 <= SCENE_RADIUS**2], minlength=len(others)) > 0
