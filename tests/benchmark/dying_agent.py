"""Agents that kill the process they run in, for the runner's dead-worker handling.

They reach worker processes through :func:`resolve` (a module-level policy resolver, so it
pickles): ``test:die-once`` kills its process on the first episode any worker plays (a marker
file in ``$SMARTS_TEST_DIE_DIR`` says it already did) and then drives like ``zoo:stand-still``;
``test:die-always`` kills its process in every episode; ``test:hang`` is stuck in its first
``act`` (for the episode timeout). Other locators go to the default resolver.
"""

from __future__ import annotations

import os
import signal
import time
from pathlib import Path

from smarts.core.policies import default_resolver

MARKER_DIR = "SMARTS_TEST_DIE_DIR"


def _die() -> None:
    os.kill(os.getpid(), signal.SIGKILL)


class DieOncePolicy:
    """Kills its own process in the first episode played anywhere (per marker folder)."""

    action_space = "relative_target_pose"

    def __init__(self):
        self.inner = default_resolver("zoo:stand-still")

    def act(self, obs):
        marker = Path(os.environ[MARKER_DIR]) / "died"
        try:
            os.close(os.open(marker, os.O_CREAT | os.O_EXCL | os.O_WRONLY))
        except FileExistsError:
            return self.inner.act(obs)
        _die()


class DieAlwaysPolicy:
    action_space = "relative_target_pose"

    def act(self, obs):
        _die()


class HangPolicy:
    """Stuck for 150 s in its first ``act`` (long past the tests' timeout, short enough that a
    broken timeout fails the test instead of hanging the suite), then stands still."""

    action_space = "relative_target_pose"

    def __init__(self):
        self.inner = default_resolver("zoo:stand-still")
        self.stuck = False

    def act(self, obs):
        if not self.stuck:
            self.stuck = True
            time.sleep(150.0)
        return self.inner.act(obs)


def resolve(locator: str, /, **kwargs):
    if locator == "test:die-once":
        return DieOncePolicy()
    if locator == "test:die-always":
        return DieAlwaysPolicy()
    if locator == "test:hang":
        return HangPolicy()
    return default_resolver(locator, **kwargs)
