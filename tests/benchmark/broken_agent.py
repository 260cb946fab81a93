"""Agents that misbehave, for the runner's failure handling."""

import numpy as np


class RaisingPolicy:
    action_space = "relative_target_pose"

    def act(self, obs):
        raise RuntimeError("planner crashed")


class NaNPolicy:
    action_space = "relative_target_pose"

    def act(self, obs):
        return np.full((len(obs["ego"]), 3), np.nan, dtype=np.float32)


class RammingPolicy:
    """Full speed straight ahead: rams whatever is in front."""

    action_space = "relative_target_pose"

    def act(self, obs):
        out = np.zeros((len(obs["ego"]), 3), dtype=np.float32)
        out[:, 0] = 2.22
        return out
