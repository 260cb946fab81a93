"""Policies that declare ``batching`` and misbehave, for the benchmark's batched path.

They reach worker processes through :func:`resolve` (a module-level resolver, so it pickles):
``test:flaky`` drives like ``zoo:keep-lane`` but raises for a row faster than 11.9 m/s and sends
NaN for a row faster than 11.3 m/s without neighbours (in the tiny suite, t2's episodes fail in
the policy late, t1's in the simulation's action check); ``test:die-once-rows`` kills its process in
the first call anywhere (marker file in ``$SMARTS_TEST_DIE_DIR``); ``test:hang-stacked`` is stuck
for 150 s in a call of more than two rows (a batch of episodes; alone an episode of the tests'
suites has at most two agents). All but ``test:flaky`` then drive like ``zoo:stand-still``.
"""

from __future__ import annotations

import os
import signal
import time
from pathlib import Path

import numpy as np

from smarts.core.policies import default_resolver
from tests.benchmark.dying_agent import MARKER_DIR


class FlakyPolicy:
    action_space = "relative_target_pose"
    batching = "rows"

    def __init__(self):
        self.inner = default_resolver("zoo:keep-lane")

    def act(self, obs):
        speed = obs["ego"][:, 0]
        alone = ~obs["neighbour_mask"].astype(bool).any(axis=1)
        if (speed > 11.9).any():
            raise RuntimeError(f"too fast: {float(speed.max()):.3f} m/s")
        actions = self.inner.act(obs)
        actions[alone & (speed > 11.3)] = np.nan
        return actions


class DieOnceRowsPolicy:
    action_space = "relative_target_pose"
    batching = "rows"

    def __init__(self):
        self.inner = default_resolver("zoo:stand-still")

    def act(self, obs):
        marker = Path(os.environ[MARKER_DIR]) / "died"
        try:
            os.close(os.open(marker, os.O_CREAT | os.O_EXCL | os.O_WRONLY))
        except FileExistsError:
            return self.inner.act(obs)
        os.kill(os.getpid(), signal.SIGKILL)


class HangStackedPolicy:
    action_space = "relative_target_pose"
    batching = "rows"

    def __init__(self):
        self.inner = default_resolver("zoo:stand-still")

    def act(self, obs):
        if len(obs["ego"]) > 2:
            time.sleep(150.0)
        return self.inner.act(obs)


def resolve(locator: str, /, **kwargs):
    known = {"test:flaky": FlakyPolicy, "test:die-once-rows": DieOnceRowsPolicy, "test:hang-stacked": HangStackedPolicy}
    if locator in known:
        return known[locator]()
    return default_resolver(locator, **kwargs)
