"""Task rewards for training: terms shaped like the benchmark metrics a task is scored with.

The scenario's default reward (metres of route progress, crash penalties, a goal bonus) makes
standing still a strong local optimum: the benchmark's safety-heavy S_bench gives a parked car about
0.6. These rewards pay for what the metrics pay for, step by step, so the optimum is to drive well.
Two rules keep their incentives straight: a step that goes on driving never earns less than
ending the episode by a crash, and (for drive) standing still costs a little every step.

Platoon (follow a lead vehicle; scored by PR, RC, Humanness and SFD), per step::

    follow * max(0, 1 - |tg - target_gap| / max_time_gap)   lead in my lane and visible, outside
                                              the follow margin FM = standstill + headway * v,
                                              tg = (gap - FM) / v; 0 inside FM or without the lead
                                              (SFD scores both as lost)
    + travel * v * dt                         metres driven (keeps a follower who lost the lead moving)

Drive (reach the exit of a junction; scored by PR, RC, Humanness and MTE), per step::

    progress * (metres of route progress) - time   (MTE pays for arriving early)
    + goal on the step the goal is reached

Both add the shared terms (the Humanness and RC ingredients, and the events)::

    + comfort * [no jerk, lateral jerk, acceleration or lateral acceleration over its comfort limit]
    + lane_centre * (1 - min(|lane offset| / (0.5 * lane width), 1))
    - speeding * min(max(v - limit, 0) / (0.5 * limit), 1)
    - wrong_way * [wrong way] - partial_off_road * [a wheel off the road]
    - red_light * [entered a junction lane from a road lane on red]   (RC's red-light rule)
    - collision * [collision] - off_road * [off road]

Every weight lives in ``configs/train/<task>.yaml`` (``reward:``); the limits default to the
benchmark's (``configs/benchmark/metrics.yaml``).
"""

from __future__ import annotations

import numpy as np

from smarts.core.events import Event
from smarts.core.following import lead_state
from smarts.core.simulation import Simulation
from smarts.env.reward_weights import RewardWeights
from smarts.traffic.signals import RED


class TaskReward:
    """``reward(sim, agents)`` for one simulation (it keeps the lateral acceleration of the last
    step to difference it into lateral jerk; build one per env)."""

    def __init__(self, weights: RewardWeights):
        self.w = weights
        self._lat = np.zeros(0)
        self._lane = np.zeros(0, dtype=np.int64)
        self._step = np.zeros(0, dtype=np.int64)

    def __call__(self, sim: Simulation, agents: np.ndarray) -> np.ndarray:
        w = self.w
        t = sim.table
        rows = sim.agent_row[agents]
        ev = sim.agent_events[agents]
        speed = np.maximum(t.speed[rows], 0.0)
        rm = sim.road_map
        lane = t.lane[rows]
        on_lane = lane >= 0
        lane_c = np.maximum(lane, 0)

        # Humanness and RC ingredients.
        if self._lat.shape[0] != len(sim.agent_ids):
            self._lat = np.zeros(len(sim.agent_ids))
            self._lane = np.full(len(sim.agent_ids), -1, dtype=np.int64)
            self._step = np.full(len(sim.agent_ids), -10, dtype=np.int64)
        lat = t.lat_accel[rows]
        step = sim.agent_step(agents)  # each agent's episode's step
        going_on = self._step[agents] == step - 1  # the agent's previous step was the one before
        previous = np.where(going_on, self._lat[agents], lat)
        lat_jerk = (lat - previous) / sim.dt
        red_light = self._red_light(sim, agents, lane, going_on) if w.red_light > 0 else 0.0
        self._lat[agents], self._lane[agents], self._step[agents] = lat, lane, step
        uncomfortable = (
            (np.abs(t.jerk[rows]) > w.jerk_long_max)
            | (np.abs(lat_jerk) > w.jerk_lat_max)
            | (np.abs(t.accel[rows]) > w.accel_long_max)
            | (np.abs(lat) > w.accel_lat_max)
        )
        centre = np.where(on_lane, np.minimum(np.abs(t.t[rows]) / (0.5 * rm.lane_width[lane_c]), 1.0), 1.0)
        limit = rm.lane_speed_limit[lane_c]
        overspeed = np.where(on_lane, np.minimum(np.maximum(speed - limit, 0.0) / (0.5 * limit), 1.0), 0.0)
        reward = (
            w.comfort * ~uncomfortable
            + w.lane_centre * (1.0 - centre)
            - w.speeding * overspeed
            - w.wrong_way * ev[:, Event.WRONG_WAY]
            - w.partial_off_road * ev[:, Event.PARTIAL_OFF_ROAD]
            - w.red_light * red_light
            - w.collision * ev[:, Event.COLLISION]
            - w.off_road * ev[:, Event.OFF_ROAD]
        )
        if w.task == "platoon":
            reward += self._platoon(sim, agents, speed)
        else:
            reward += w.progress * sim.route_progress_delta[agents] - w.time
            reward += w.goal * ev[:, Event.REACHED_GOAL]
        return reward

    def _red_light(self, sim: Simulation, agents: np.ndarray, lane: np.ndarray, going_on: np.ndarray) -> np.ndarray:
        """1 where the agent entered, on this step, from a road lane a junction lane whose signal
        (its own episode's) is red now: the benchmark recorder's red-light rule, so the reward
        counts what RC counts (moving on from one junction lane to another is not entering)."""
        colours = getattr(sim, "via_colour", None)
        if colours is None or not colours.any():
            return np.zeros(len(agents))
        prev = np.where(going_on, self._lane[agents], lane)  # an episode's first step enters nothing
        internal = sim.road_map.lane_internal
        from_road = (prev < 0) | ~internal[np.maximum(prev, 0)]
        entered = (lane >= 0) & (lane != prev) & from_road
        colour = colours[sim.agent_episode[agents], np.maximum(lane, 0)]
        return (entered & (colour == RED)).astype(np.float64)

    def _platoon(self, sim: Simulation, agents: np.ndarray, speed: np.ndarray) -> np.ndarray:
        w = self.w
        lead = lead_state(sim, agents)
        gap = np.nan_to_num(lead.gap, nan=0.0)
        margin = w.standstill_distance + w.headway * speed
        outside = lead.in_lane & (gap > margin)
        with np.errstate(divide="ignore", invalid="ignore"):
            time_gap = np.where(outside, (gap - margin) / np.maximum(speed, 1e-6), np.inf)
        follow = np.where(outside, np.clip(1.0 - np.abs(time_gap - w.target_gap) / w.max_time_gap, 0.0, 1.0), 0.0)
        return w.follow * follow + w.travel * speed * sim.dt


def reward_factory(weights: RewardWeights):
    """A no-argument constructor of one ``TaskReward`` per env (picklable for worker processes)."""
    import functools

    return functools.partial(TaskReward, weights)
