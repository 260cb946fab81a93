"""A stand-still driver: brakes smoothly to a stop and stays there (a benchmark floor).

It reads only the observation (``smarts.sensors.observation``) and acts in RelativeTargetPose.
While it still moves it follows its lane (the route's waypoints, or the lane centre from the ego
features when there are none); the deceleration ramps up and down at a bounded jerk so the ride
stays inside the humanness comfort limits (``configs/benchmark/metrics.yaml``: |accel| <= 2
m/s^2, |jerk| <= 0.9 m/s^3; at most 1.5 m/s^2 and 0.5 m/s^3 here). Steering follows the lane as
it is drawn: a kink in a lane's polyline (a sharp corner) is a lateral spike for it as for any
lane follower. Doing nothing is safe but makes no progress: its S_bench shows what
the safety-heavy weights give for free.

The braking profile is stateless (read from the observed speed and acceleration), so one policy
drives any number of agents: the commanded acceleration is about ``-min(max_decel, sqrt(2 jerk
v))`` (exactly: the deceleration that, easing off by ``jerk * dt`` each step, reaches zero in the
step the speed does), moved from the observed acceleration by at most ``jerk * dt`` per step.
"""

from __future__ import annotations

import numpy as np

from agents.obs_columns import Ego, Waypoint, WaypointPath

ACTION_SPACE = "relative_target_pose"
AIM_POINT = 1
"""The route waypoint a step heads for, as keep-lane's."""


class StandStillPolicy:
    """Batched: ``act`` maps observations ``{key: [n, ...]}`` of n agents to actions [n, 3]."""

    action_space = ACTION_SPACE
    batching = "rows"  # row by row, no state: the benchmark stacks the rows of many episodes

    def __init__(self, max_decel: float = 1.5, jerk: float = 0.5, dt: float = 0.1):
        self.max_decel = max_decel
        self.jerk = jerk
        self.dt = dt

    def act(self, obs: dict[str, np.ndarray]) -> np.ndarray:
        ego = obs["ego"].astype(np.float64)
        speed = np.maximum(ego[:, Ego.SPEED], 0.0)
        accel = np.clip(ego[:, Ego.ACCEL], -self.max_decel, self.max_decel)
        # Deceleration that fades out, one jerk step per step, exactly as the speed reaches zero:
        # m steps of -m, -(m-1), ..., -1 times jerk*dt shed v = jerk dt^2 m (m+1) / 2.
        step = self.jerk * self.dt
        m = 0.5 * (np.sqrt(1.0 + 8.0 * speed / (step * self.dt)) - 1.0)
        want = -np.minimum(self.max_decel, step * m)
        a = np.clip(want, accel - step, accel + step)
        new_speed = np.maximum(speed + a * self.dt, 0.0)
        dist = new_speed * self.dt
        # Direction: the route's next waypoints (as keep-lane); without them, back to the lane centre.
        wp = obs["waypoints"][:, WaypointPath.ROUTE, AIM_POINT].astype(np.float64)  # [n, 3] in the ego frame
        has_wp = obs["waypoint_mask"][:, WaypointPath.ROUTE, AIM_POINT] > 0
        x, y, heading = wp[:, Waypoint.X], wp[:, Waypoint.Y], wp[:, Waypoint.HEADING]
        length = np.maximum(np.hypot(x, y), 1e-6)
        scale = np.where(has_wp, dist / length, 0.0)
        action = np.stack([x * scale, y * scale, heading * scale], axis=1)
        lane = ~has_wp & (dist > 0)
        if lane.any():
            action[lane, 0] = dist[lane]
            action[lane, 1] = np.clip(-ego[lane, Ego.LANE_OFFSET], -0.05, 0.05)
            action[lane, 2] = np.clip(-ego[lane, Ego.HEADING_ERROR], -0.02, 0.02)
        action[dist <= 0] = 0.0
        return action.astype(np.float32)
