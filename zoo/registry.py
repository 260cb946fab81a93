"""Ready agents by locator: ``zoo:<name>`` (or just ``<name>``) -> a policy object.

A policy is batched: ``policy.act(obs)`` takes ``{key: [n, ...]}`` observations of n agents and
returns their actions ``[n, k]``; ``policy.action_space`` names the simulator action space it
acts in (relative_target_pose | target_pose | continuous | lane). It may also declare
``policy.controller`` (``direct`` when absent, or ``lane_relative``) and ``policy.interface`` (an
``AgentInterface``; None or absent: the scenario's observation). The benchmark runs every agent
in its own action space, controller and interface.

Reference agents (benchmarked beside every agent, ``smarts.benchmark.runner.REFERENCE_AGENTS``):
``zoo:keep-lane`` (IDM on the route's waypoints), ``zoo:random`` (uniform random steps) and
``zoo:stand-still`` (brakes gently to a stop: the floor that doing nothing scores). PPO baselines
are checkpoints with model cards under ``zoo/cards/`` (``cards/stand-still.md`` describes the
floor).
"""

from __future__ import annotations

import importlib
from pathlib import Path
from typing import Any

ZOO_DIR = Path(__file__).resolve().parent
CHECKPOINT = "checkpoint"
"""A ZOO entry whose module is CHECKPOINT names a checkpoint file under zoo/ instead of a class."""

ZOO: dict[str, tuple[str, str, str]] = {
    "keep-lane": ("agents.keep_lane", "KeepLanePolicy", "IDM speed on the route's waypoints"),
    "random": ("agents.random_agent", "RandomPolicy", "uniform random relative-pose steps"),
    "stand-still": ("agents.stand_still", "StandStillPolicy", "brakes gently to a stop and stays (the do-nothing floor)"),
    "platoon-rtp": (CHECKPOINT, "checkpoints/platoon-rtp.pt", "PPO following, RelativeTargetPose (cards/)"),
    "drive": (CHECKPOINT, "checkpoints/drive.pt", "PPO turning at intersections, RelativeTargetPose (cards/)"),
    "platoon-c": (CHECKPOINT, "checkpoints/platoon-c.pt", "PPO following, Continuous on the pybullet car (cards/)"),
}
"""name -> (module, class, one-line description)."""


def make_policy(locator: str, **kwargs: Any):
    """Build the policy a locator names; unknown names raise ValueError listing the known ones."""
    name = locator[len("zoo:") :] if locator.startswith("zoo:") else locator
    if name not in ZOO:
        raise ValueError(f"unknown agent locator {locator!r}; known: {', '.join('zoo:' + n for n in ZOO)}")
    module, target, _ = ZOO[name]
    if module == CHECKPOINT:
        from agents.ppo import load_policy_file

        return load_policy_file(ZOO_DIR / target)
    return getattr(importlib.import_module(module), target)(**kwargs)
