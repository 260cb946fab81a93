"""Record the per-step episode log that the benchmark metrics score.

The simulation side of the metric contract: while an episode runs, ``EpisodeRecorder.record`` appends one
row per mission agent per step from the simulation's arrays (no per-vehicle Python work beyond the
agents); ``finish`` returns an ``EpisodeLog`` (see ``smarts.benchmark.metrics.log`` for the
columns). Scoring never touches the simulator, so logs written here can be re-scored later.

Route distance to the goal: along the mission's route path, plus the lateral distance to it. In
following tasks the goal is where the lead vehicle is when the episode ends, so those distances
are filled in at ``finish`` along the lane route from the agent's start to the lead's final lane.
"""

from __future__ import annotations

import math

import numpy as np

from smarts.benchmark.metrics.log import AgentTrace, EpisodeLog
from smarts.benchmark.metrics.params import MetricParams
from smarts.benchmark.metrics.scores import time_gap_to_margin
from smarts.core.events import Event
from smarts.core.simulation import Simulation
from smarts.maps import MapError, project, route_polyline, shortest_route

_COLUMNS = (
    "time", "x", "y", "heading", "speed", "accel_long", "accel_lat", "jerk_long", "jerk_lat",
    "lane_offset", "lane_width", "speed_limit", "route_distance_to_goal", "follow_time_gap",
)  # fmt: skip
_FLAGS = (
    "wrong_way", "partial_off_road", "off_road", "goal_reached", "in_follow_margin",
    "lead_in_lane_and_visible",
)  # fmt: skip


class EpisodeRecorder:
    """Collects the log of the learner agents of one episode.

    ``follow`` maps agent ids to the vehicle id they follow (adaptive tasks); ``sight`` is how far
    a lead vehicle counts as visible (m).
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
        sight: float = 50.0,
    ):
        self.sim = sim
        self.agent_ids = list(agent_ids)
        self.agents = np.array([sim.agent_index[a] for a in self.agent_ids], dtype=np.int64)
        self.meta = dict(scenario=scenario, task=task, episode=episode, seed=seed, time_limit=time_limit)
        self.follow = dict(follow or {})
        self.params = params or MetricParams()
        self.sight = sight
        self.rows: dict[str, list[np.ndarray]] = {a: [] for a in self.agent_ids}
        self.lead_final: dict[str, tuple[float, float]] = {}
        self.failure: str | None = None
        self._prev_lat = np.full(len(sim.agent_ids), np.nan)

    def record(self) -> None:
        """Append this step's row for every agent still in the episode."""
        sim, t, rm = self.sim, self.sim.table, self.sim.road_map
        live = sim.agent_active[self.agents]
        if not live.any():
            return
        agents = self.agents[live]
        rows = sim.agent_row[agents]
        ma = sim.mission_arrays
        lane = np.maximum(t.lane[rows], 0)
        speed = t.speed[rows]
        # Lateral distance to the route: to the matched route point.
        point = ma.paths[agents, sim.route_index[agents], 0, :2]
        off_route = np.hypot(t.x[rows] - point[:, 0], t.y[rows] - point[:, 1])
        to_goal = ma.route_length[agents] - sim.route_progress[agents] + off_route
        ev = sim.agent_events[agents]
        gap, in_margin, visible = self._follow_state(agents, rows)
        values = np.stack(
            [
                np.full(len(agents), sim.time), t.x[rows], t.y[rows], t.heading[rows], speed,
                t.accel[rows], t.lat_accel[rows], t.jerk[rows], self._lat_jerk(agents, rows),
                t.t[rows], rm.lane_width[lane], rm.lane_speed_limit[lane], to_goal, gap,
                ev[:, Event.WRONG_WAY], ev[:, Event.PARTIAL_OFF_ROAD], ev[:, Event.OFF_ROAD],
                ev[:, Event.REACHED_GOAL], in_margin, visible,
            ],
            axis=1,
        )  # fmt: skip
        for k, a in enumerate(np.flatnonzero(live)):
            self.rows[self.agent_ids[a]].append(values[k])
        for agent_id, lead_id in self.follow.items():
            lead_row = t.row_of.get(lead_id)
            if lead_row is not None:
                self.lead_final[agent_id] = (float(t.x[lead_row]), float(t.y[lead_row]))

    def _lat_jerk(self, agents: np.ndarray, rows: np.ndarray) -> np.ndarray:
        """Lateral jerk by differencing lateral acceleration between recorded steps (0 at first)."""
        lat = self.sim.table.lat_accel[rows]
        out = np.where(np.isnan(self._prev_lat[agents]), 0.0, (lat - self._prev_lat[agents]) / self.sim.dt)
        self._prev_lat[agents] = lat
        return out

    def _follow_state(self, agents: np.ndarray, rows: np.ndarray):
        n = len(agents)
        gap = np.full(n, np.nan)
        in_margin = np.zeros(n)
        visible = np.zeros(n)
        if not self.follow:
            return gap, in_margin, visible
        t = self.sim.table
        for k, a in enumerate(agents.tolist()):
            lead_id = self.follow.get(self.sim.agent_ids[a])
            lead = t.row_of.get(lead_id) if lead_id else None
            if lead is None:
                continue
            r = rows[k]
            dx, dy = t.x[lead] - t.x[r], t.y[lead] - t.y[r]
            ahead = dx * math.cos(t.heading[r]) + dy * math.sin(t.heading[r])
            distance = ahead - 0.5 * (t.length[lead] + t.length[r])  # bumper to bumper
            same_lane = t.lane[lead] == t.lane[r] and t.lane[r] >= 0
            if not (same_lane and 0.0 < ahead <= self.sight):
                continue
            visible[k] = 1.0
            gap[k], inside = time_gap_to_margin(distance, float(t.speed[r]), self.params)
            in_margin[k] = float(inside)
        return gap, in_margin, visible

    def fail(self, reason: str) -> None:
        self.failure = reason

    def finish(self) -> EpisodeLog:
        traces = {}
        initial = {}
        for agent_id, rows in self.rows.items():
            if not rows:
                continue
            data = np.array(rows)
            cols = {name: data[:, i] for i, name in enumerate(_COLUMNS)}
            flags = {name: data[:, len(_COLUMNS) + i] > 0.5 for i, name in enumerate(_FLAGS)}
            if agent_id in self.follow:
                cols["route_distance_to_goal"] = self._distance_to_lead_end(agent_id, cols)
            traces[agent_id] = AgentTrace(**cols, **flags)
            initial[agent_id] = float(cols["route_distance_to_goal"][0])
        sim = self.sim
        radii = [float(sim.mission_arrays.goal_radius[sim.agent_index[a]]) for a in traces]
        return EpisodeLog(
            **self.meta,
            dt=sim.dt,
            goal_radius=max(radii, default=0.0),
            initial_route_distance=initial,
            agents=traces,
            failure=self.failure,
        )

    def _distance_to_lead_end(self, agent_id: str, cols: dict[str, np.ndarray]) -> np.ndarray:
        """Route distance from each logged position to where the lead was at the end."""
        rm = self.sim.road_map
        end = self.lead_final.get(agent_id)
        xy = np.stack([cols["x"], cols["y"]], axis=1)
        if end is None:
            return np.zeros(len(xy))
        start = project(rm, xy[:1], cols["heading"][:1])
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
