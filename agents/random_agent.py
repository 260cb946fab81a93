"""A random driver: uniform actions from its action space (a lower bound for the benchmark)."""

from __future__ import annotations

import numpy as np


class RandomPolicy:
    """Batched uniform random actions; seeded so benchmark runs repeat exactly."""

    batching = "instances"  # draws from its own generator: one seeded instance per benchmark episode

    def __init__(self, action_space: str = "relative_target_pose", low=None, high=None, seed: int = 0):
        self.action_space = action_space
        if low is None or high is None:
            # A relative pose step of up to ~1.5 m forward, a little sideways and turning.
            low, high = [0.0, -0.2, -0.1], [1.5, 0.2, 0.1]
        self.low = np.asarray(low, dtype=np.float32)
        self.high = np.asarray(high, dtype=np.float32)
        self.rng = np.random.default_rng(seed)

    def seed(self, seed: int) -> None:
        self.rng = np.random.default_rng(seed)

    def act(self, obs: dict[str, np.ndarray]) -> np.ndarray:
        n = len(next(iter(obs.values())))
        return self.rng.uniform(self.low, self.high, size=(n, len(self.low))).astype(np.float32)
