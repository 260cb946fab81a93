"""A keep-lane driver: follows its route's waypoints and keeps a safe gap to the vehicle ahead.

It reads only the observation (``smarts.sensors.observation``) and acts in RelativeTargetPose, so
it works as a social agent, as a benchmark reference and as a baseline for learned policies. The
speed choice is the Intelligent Driver Model; the path is the route's waypoint polyline.
"""

from __future__ import annotations

import numpy as np

from agents.obs_columns import Ego, Neighbour, Signal, Waypoint, WaypointPath

ACTION_SPACE = "relative_target_pose"
AIM_POINT = 1
"""The route waypoint a step heads for: the second (the first is the ego's own route point)."""


class KeepLanePolicy:
    """Batched: ``act`` maps observations ``{key: [n, ...]}`` of n agents to actions [n, 3]."""

    action_space = ACTION_SPACE
    batching = "rows"  # row by row, no state: the benchmark stacks the rows of many episodes

    def __init__(
        self,
        speed: float | None = None,
        accel: float = 2.0,
        decel: float = 3.0,
        time_gap: float = 1.5,
        min_gap: float = 3.0,
        dt: float = 0.1,
    ):
        self.speed = speed  # None: the lane's speed limit
        self.accel, self.decel = accel, decel
        self.time_gap, self.min_gap = time_gap, min_gap
        self.dt = dt

    def act(self, obs: dict[str, np.ndarray]) -> np.ndarray:
        ego, nb, mask = obs["ego"], obs["neighbours"], obs["neighbour_mask"]
        speed = ego[:, Ego.SPEED].astype(np.float64)
        desired = np.full_like(speed, self.speed) if self.speed is not None else ego[:, Ego.SPEED_LIMIT]
        desired = np.maximum(desired, 0.1)
        # Leader: the nearest neighbour ahead within half a lane of our line.
        half_lane = 0.5 * np.maximum(ego[:, Ego.LANE_WIDTH, None], 2.5)
        ahead = (mask > 0) & (nb[..., Neighbour.DX] > 0) & (np.abs(nb[..., Neighbour.DY]) < half_lane)
        bumper_gap = nb[..., Neighbour.DX] - 0.5 * (nb[..., Neighbour.LENGTH] + ego[:, Ego.LENGTH, None])
        gap = np.where(ahead, bumper_gap, np.inf).min(axis=1)
        if "signal" in obs:  # a red or yellow light ahead is a standing leader at its stop line
            sig = obs["signal"]
            red_or_yellow = sig[:, Signal.RED] + sig[:, Signal.YELLOW] > 0
            stop = red_or_yellow & (sig[:, Signal.STOP_DISTANCE] > 0.5 * ego[:, Ego.LENGTH])
            gap = np.where(stop, np.minimum(gap, sig[:, Signal.STOP_DISTANCE] - 0.5 * ego[:, Ego.LENGTH]), gap)
        closing = np.where(ahead, -nb[..., Neighbour.VX], 0.0)  # ego speed minus leader speed along x
        first = np.where(ahead, nb[..., Neighbour.DX], np.inf).argmin(axis=1)
        closing = closing[np.arange(len(speed)), first]
        s_star = self.min_gap + speed * self.time_gap + speed * closing / (2 * np.sqrt(self.accel * self.decel))
        free = 1.0 - (speed / desired) ** 4
        interaction = np.where(np.isfinite(gap), (np.maximum(s_star, 0.0) / np.maximum(gap, 0.1)) ** 2, 0.0)
        a = np.clip(self.accel * (free - interaction), -9.0, self.accel)
        step = np.maximum(speed + a * self.dt, 0.0) * self.dt
        # Move that far along the route towards the route's next waypoint.
        wp = obs["waypoints"][:, WaypointPath.ROUTE, AIM_POINT]  # [n, 3] in the ego frame
        x, y, heading = wp[:, Waypoint.X], wp[:, Waypoint.Y], wp[:, Waypoint.HEADING]
        length = np.maximum(np.hypot(x, y), 1e-6)
        scale = np.where(obs["waypoint_mask"][:, WaypointPath.ROUTE, AIM_POINT] > 0, step / length, 0.0)
        action = np.stack([x * scale, y * scale, heading * scale], axis=1)
        action[scale == 0.0, 0] = step[scale == 0.0]  # no route left: straight ahead
        return action.astype(np.float32)
