"""Ready agents by locator: ``zoo:<name>`` (or just ``<name>``, or a checkpoint file) -> a policy.

A policy is batched: ``policy.act(obs)`` takes ``{key: [n, ...]}`` observations of n agents and
returns their actions ``[n, k]``; ``policy.action_space`` names the simulator action space it
acts in (relative_target_pose | target_pose | continuous | lane). It may also declare
``policy.controller`` (``direct`` when absent, or ``lane_relative``), ``policy.interface`` and
``policy.lane_relative`` (plain data the simulator validates; None or absent: the scenario's
observation, the default settings). The benchmark runs every agent in its own action space,
controller and interface.

``make_policy`` is the simulator's default policy resolver (``smarts.core.policies``, registered as
an entry point in ``pyproject.toml``): the simulator reaches the zoo through it, never by import.

Reference agents (benchmarked beside every agent, ``smarts.benchmark.agents.REFERENCE_AGENTS``):
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
    "stand-still": (
        "agents.stand_still",
        "StandStillPolicy",
        "brakes gently to a stop and stays (the do-nothing floor)",
    ),
    "platoon-rtp": (CHECKPOINT, "checkpoints/platoon-rtp.pt", "PPO following, RelativeTargetPose (cards/)"),
    "drive": (CHECKPOINT, "checkpoints/drive.pt", "PPO turning at intersections, RelativeTargetPose (cards/)"),
    "platoon-c": (CHECKPOINT, "checkpoints/platoon-c.pt", "PPO following, Continuous on the pybullet car (cards/)"),
    "tf": ("zoo.planners", "tf", "TF driving rules with the behaviour-cloned stop/move veto (cards/tf.md)"),
    "tf-rules": (
        "agents.planners.tf",
        "TFPlanner",
        "TF driving rules without the learned stop/move veto (cards/tf.md)",
    ),
    "vcr": (
        "zoo.planners",
        "vcr",
        "VCR Bezier follower, speed from the learned event classifier over rasters (cards/vcr.md)",
    ),
    "vcr-ttc": (
        "agents.planners.vcr",
        "VCRPlanner",
        "VCR Bezier follower, speed from a time-to-collision rule (cards/vcr.md)",
    ),
    "aid": ("zoo.planners", "aid", "AID Frenet sampling planner over its learned motion predictor (cards/aid.md)"),
    "aid-cv": (
        "agents.planners.aid",
        "AIDPlanner",
        "AID Frenet sampling planner, constant-velocity prediction (cards/aid.md)",
    ),
}
"""name -> (module, class, one-line description)."""


def is_checkpoint_path(locator: str) -> bool:
    """A locator that names a checkpoint file (``*.pt``, or any existing file) rather than an agent."""
    return locator.endswith(".pt") or Path(locator).is_file()


def make_policy(locator: str, **kwargs: Any):
    """Build the policy a locator names (``kwargs`` go to an agent class); a checkpoint path loads
    that file. Unknown names raise ValueError listing the known ones."""
    name = locator.removeprefix("zoo:")
    if name not in ZOO:
        if name == locator and is_checkpoint_path(locator):
            return _load_file(Path(locator), kwargs)
        known = ", ".join("zoo:" + n for n in ZOO)
        raise ValueError(f"unknown agent locator {locator!r}; known: {known}, or a checkpoint file (*.pt)")
    module, target, _ = ZOO[name]
    if module == CHECKPOINT:
        return _load_file(ZOO_DIR / target, kwargs)
    return getattr(importlib.import_module(module), target)(**kwargs)


def _load_file(path: Path, kwargs: dict[str, Any]):
    from agents.checked import load_checkpoint_policy

    if kwargs:
        raise TypeError(f"{path}: a checkpoint policy takes no options, got {', '.join(sorted(kwargs))}")
    return load_checkpoint_policy(path)  # its settings without torch when the file was checked before
