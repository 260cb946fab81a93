"""Agents that declare their action space, controller or interface, for the runner's tests."""

import numpy as np

from smarts.sensors.interface import AgentInterface, EgoInterface


class ThrottlePolicy:
    """Continuous (throttle, brake, steering): a steady throttle, straight ahead."""

    action_space = "continuous"

    def act(self, obs):
        n = len(obs["ego"])
        return np.tile(np.array([[0.6, 0.0, 0.0]], dtype=np.float32), (n, 1))


class LanePolicy:
    """The lane action space: a different vehicle model the benchmark suites do not host."""

    action_space = "lane"

    def act(self, obs):
        return np.zeros((len(obs["ego"]), 2), dtype=np.float32)


class ExtendedEgoPolicy:
    """Reads the extended ego features (13 columns): fails unless the runner honours its interface."""

    action_space = "relative_target_pose"
    interface = AgentInterface(ego=EgoInterface(extended=True))

    def act(self, obs):
        if obs["ego"].shape[1] != 13:
            raise RuntimeError(f"expected the extended ego block, got {obs['ego'].shape[1]} columns")
        speed = obs["ego"][:, 0]
        return np.stack([speed * 0.1, 0 * speed, 0 * speed], axis=1).astype(np.float32)


class BadControllerPolicy:
    action_space = "relative_target_pose"
    controller = "telepathy"

    def act(self, obs):
        return np.zeros((len(obs["ego"]), 3), dtype=np.float32)
