"""What the planners' training commands share: their options, the suites' scenarios, the
held-out split by scenario and the cars and envs of scripted situations."""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import TypeVar

T = TypeVar("T")


def split_held_out(items: list[T], every: int = 5) -> tuple[list[T], list[T]]:
    """``(train, held out)``: every ``every``-th item in sorted order is held out (the last one when
    there are fewer), so no scenario is seen in both."""
    items = sorted(items)
    held = items[every - 1 :: every] or items[-1:]
    rest = [item for item in items if item not in held]
    if not rest:
        raise ValueError(f"need at least 2 scenarios to hold some out, got {len(items)}")
    return rest, held


def add_run_options(p: argparse.ArgumentParser) -> None:
    """``--threads``, ``--seed`` and ``--quiet``, as every training command takes them."""
    p.add_argument("--threads", type=int, default=1, help="torch CPU threads")
    p.add_argument("--seed", type=int, default=0, help="sampling and initialisation seed")
    p.add_argument("--quiet", action="store_true", help="no progress bar")


def apply_run_options(args: argparse.Namespace) -> None:
    """Seed torch and set its threads from ``add_run_options``' values, and check the output folder
    (``--out``) before any data is generated: one that refuses writes or lacks room fails now."""
    import torch

    from train.run import check_run_folder

    if getattr(args, "out", None):
        check_run_folder(Path(args.out))
    torch.manual_seed(args.seed)
    torch.set_num_threads(args.threads)


def suite_scenarios(suites: list[str] | None) -> list:
    """Every scenario entry of ``suites`` (default: both benchmark suites), in suite order."""
    from smarts.benchmark.suites import load_suite

    return [e for name in suites or ["collaborative", "adaptive"] for e in load_suite(name).scenarios]


def road_car(lane: int, offset: float, speed: float, policy: str | None = None, heading: float | None = None) -> dict:
    """A car on the straight built-in maps' road ``main`` (endless mission): the explorer or
    demonstrator when ``policy`` is None, else a social agent; ``heading`` (rad, world) turns it
    away from the lane's direction (the road runs along heading 0)."""
    start = {"road": "main", "lane": lane, "offset": round(offset, 1), "speed": round(speed, 2)}
    if heading is not None:
        start["heading"] = round(heading, 3)
    car = {"action_space": "relative_target_pose", "mission": {"start": start, "goal": {"endless": True}}}
    return {**car, "policy": policy} if policy else car


def situation_env(name: str, scenario: dict, observation, source: str, seed: int):
    """A scripted situation (a scenario dict of ``road_car`` cars) as a started env: ``(env, obs)``."""
    from smarts.env import DrivingParallelEnv
    from smarts.scenario import read_scenario

    env = DrivingParallelEnv(read_scenario({"name": name, **scenario}, source=source), observation=observation)
    obs, _ = env.reset(seed=seed)
    return env, obs
