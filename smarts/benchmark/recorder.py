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
"""

from __future__ import annotations

from typing import Any

import numpy as np

from smarts.benchmark.metrics.log import TIME_LIMIT_TOLERANCE, AgentTrace, EpisodeLog
from smarts.benchmark.metrics.params import MetricParams
from smarts.benchmark.metrics.scores import time_gap_to_margin
from smarts.core.errors import MapError
from smarts.core.events import Event
from smarts.core.following import LEAD_SIGHT, lead_state
from smarts.core.missions import GOAL_ROAD
from smarts.core.simulation import Simulation
from smarts.maps import project, route_polyline, shortest_route

_COLUMNS = (
    "time", "x", "y", "heading", "speed", "accel_long", "accel_lat", "jerk_long", "jerk_lat",
    "lane_offset", "lane_width", "speed_limit", "route_distance_to_goal", "follow_time_gap",
)  # fmt: skip
_FLAGS = (
    "wrong_way", "partial_off_road", "off_road", "goal_reached", "in_follow_margin",
    "lead_in_lane_and_visible",
)  # fmt: skip


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
        self.lead_final: dict[str, tuple[float, float]] = {}
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
        off_route = np.abs(-(t.x[rows] - point[:, 0]) * np.sin(point[:, 2]) + (t.y[rows] - point[:, 1]) * np.cos(point[:, 2]))
        return np.maximum(self._goal_s[agents] - sim.route_progress[agents], 0.0) + off_route

    def _goal_along_route(self) -> np.ndarray:
        """Per agent index: the route arc length of the goal. The route path of a road goal runs
        to the end of the goal lane; the goal is at the goal's offset on that lane, so the rest
        of the lane is not distance still to drive."""
        rm = self.sim.road_map
        out = np.array(self.sim.mission_arrays.route_length, dtype=np.float64)
        for a, m in enumerate(self.sim.missions):
            if m.goal_kind == GOAL_ROAD and len(m.path_lane):
                beyond = float(rm.lane_length[int(m.path_lane[-1])]) - float(m.goal_s)
                out[a] = max(float(m.path_s[-1]) - max(beyond, 0.0), 0.0)
        return out

    def _note_leads(self) -> None:
        t = self.sim.table
        for agent_id, lead_id in self.follow.items():
            lead_row = t.row_of.get(lead_id)
            if lead_row is not None:
                self.lead_final[agent_id] = (float(t.x[lead_row]), float(t.y[lead_row]))

    def record(self) -> None:
        """Append the row of every agent still in the episode, for the step just taken.

        A call before any step (at the reset state) or after the time limit writes nothing."""
        sim, t, rm = self.sim, self.sim.table, self.sim.road_map
        if sim.time <= self.start_time + 1e-9:
            return  # the reset state is not a row
        if sim.time - self.start_time > self.meta["time_limit"] + TIME_LIMIT_TOLERANCE:
            return  # past the time limit: the episode is over for the metrics
        self.end_time = float(sim.time - self.start_time)
        live = sim.agent_active[self.agents]
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
        values = np.stack(
            [
                np.full(len(agents), sim.time - self.start_time), t.x[rows], t.y[rows], t.heading[rows],
                speed, t.accel[rows], t.lat_accel[rows], t.jerk[rows], self._lat_jerk(agents, rows),
                t.t[rows], rm.lane_width[lane], rm.lane_speed_limit[lane], to_goal, gap,
                ev[:, Event.WRONG_WAY], ev[:, Event.PARTIAL_OFF_ROAD], ev[:, Event.OFF_ROAD],
                ev[:, Event.REACHED_GOAL], in_margin, visible,
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
        d2 = ((xy[:, None, :] - path.xy[None, : goal_i + 1, :]) ** 2).sum(axis=2)
        nearest = d2.argmin(axis=1)
        return path.s[goal_i] - path.s[nearest] + np.sqrt(d2[np.arange(len(xy)), nearest])
