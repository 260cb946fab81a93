"""Ready agents by locator: ``zoo:<name>`` (or just ``<name>``) -> a policy object.

A policy is batched: ``policy.act(obs)`` takes ``{key: [n, ...]}`` observations of n agents and
returns their actions ``[n, k]``; ``policy.action_space`` names the action space it uses.
"""

from __future__ import annotations

import importlib
from typing import Any

ZOO: dict[str, tuple[str, str, str]] = {
    "keep-lane": ("agents.keep_lane", "KeepLanePolicy", "IDM speed on the route's waypoints"),
    "random": ("agents.random_agent", "RandomPolicy", "uniform random relative-pose steps"),
}
"""name -> (module, class, one-line description)."""


def make_policy(locator: str, **kwargs: Any):
    """Build the policy a locator names; unknown names raise ValueError listing the known ones."""
    name = locator[len("zoo:") :] if locator.startswith("zoo:") else locator
    if name not in ZOO:
        raise ValueError(f"unknown agent locator {locator!r}; known: {', '.join('zoo:' + n for n in ZOO)}")
    module, cls, _ = ZOO[name]
    return getattr(importlib.import_module(module), cls)(**kwargs)
