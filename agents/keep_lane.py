"""A keep-lane driver: follows its route's waypoints and keeps a safe gap to the vehicle ahead.

It reads only the observation (``smarts.sensors.observation``) and acts in RelativeTargetPose, so
it works as a social agent, as a benchmark reference and as a baseline for learned policies. The
speed choice is the Intelligent Driver Model; the path is the route's waypoint polyline.
"""

from __future__ import annotations

import numpy as np

ACTION_SPACE = "relative_target_pose"


class KeepLanePolicy:
    """Batched: ``act`` maps observations ``{key: [n, ...]}`` of n agents to actions [n, 3]."""

    action_space = ACTION_SPACE

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
        speed = ego[:, 0].astype(np.float64)
        desired = np.full_like(speed, self.speed) if self.speed is not None else ego[:, 9]
        desired = np.maximum(desired, 0.1)
        # Leader: the nearest neighbour ahead within half a lane of our line.
        half_lane = 0.5 * np.maximum(ego[:, 8:9], 2.5)
        ahead = (mask > 0) & (nb[..., 0] > 0) & (np.abs(nb[..., 1]) < half_lane)
        gap = np.where(ahead, nb[..., 0] - 0.5 * (nb[..., 6] + ego[:, 10:11]), np.inf).min(axis=1)
        if "signal" in obs:  # a red or yellow light ahead is a standing leader at its stop line
            sig = obs["signal"]
            stop = (sig[:, 0] + sig[:, 1] > 0) & (sig[:, 3] > 0.5 * ego[:, 10])
            gap = np.where(stop, np.minimum(gap, sig[:, 3] - 0.5 * ego[:, 10]), gap)
        closing = np.where(ahead, -nb[..., 4], 0.0)  # ego speed minus leader speed along x
        first = np.where(ahead, nb[..., 0], np.inf).argmin(axis=1)
        closing = closing[np.arange(len(speed)), first]
        s_star = self.min_gap + speed * self.time_gap + speed * closing / (2 * np.sqrt(self.accel * self.decel))
        free = 1.0 - (speed / desired) ** 4
        interaction = np.where(np.isfinite(gap), (np.maximum(s_star, 0.0) / np.maximum(gap, 0.1)) ** 2, 0.0)
        a = np.clip(self.accel * (free - interaction), -9.0, self.accel)
        step = np.maximum(speed + a * self.dt, 0.0) * self.dt
        # Move that far along the route towards the waypoint two points ahead.
        wp = obs["waypoints"][:, 0, 1]  # [n, 3] (x, y, heading) in the ego frame
        length = np.maximum(np.hypot(wp[:, 0], wp[:, 1]), 1e-6)
        scale = np.where(obs["waypoint_mask"][:, 0, 1] > 0, step / length, 0.0)
        action = np.stack([wp[:, 0] * scale, wp[:, 1] * scale, wp[:, 2] * scale], axis=1)
        action[scale == 0.0, 0] = step[scale == 0.0]  # no route left: straight ahead
        return action.astype(np.float32)
