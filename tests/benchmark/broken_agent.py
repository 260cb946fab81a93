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


class TorchProbePolicy:
    """Says, by failing, whether its worker had imported torch: a policy of code alone."""

    action_space = "relative_target_pose"

    def act(self, obs):
        import sys

        raise RuntimeError(f"torch imported: {'torch' in sys.modules}")


class NetworkProbePolicy:
    """A policy that needs torch (imported as it is built), saying by failing how many threads torch uses."""

    action_space = "relative_target_pose"

    def __init__(self):
        import torch

        self.torch = torch

    def act(self, obs):
        raise RuntimeError(f"torch threads: {self.torch.get_num_threads()}")


def probe_resolver(locator: str, **kwargs):
    """``test:code-probe`` and ``test:net-probe``; anything else from the installed resolvers."""
    from smarts.core.policies import default_resolver

    if locator == "test:code-probe":
        return TorchProbePolicy()
    if locator == "test:net-probe":
        return NetworkProbePolicy()
    return default_resolver(locator, **kwargs)
