"""PPO learns, with either library: a short run on a tiny task with a known optimum improves its
return and its held-out evaluation beyond a random policy.

The task: follow a lead down an empty straight road with raw RelativeTargetPose actions (the
``direct`` controller). A fresh policy's actions average (0, 0, 0): it barely moves, wobbles and
earns little or negative reward; driving straight behind the lead at its speed is the optimum.
12k steps (a little under a minute on 2 cores) are enough for both libraries to learn to drive
forward and stay on the road. Settings are the task config's except the budget.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

from train.__main__ import main

SUITE = Path(__file__).with_name("straight_follow_suite.yaml")


def _scalars(folder: Path, tag: str) -> np.ndarray:
    events = EventAccumulator(str(folder), size_guidance={"scalars": 0})
    events.Reload()
    return np.array([e.value for e in events.Scalars(tag)])


@pytest.mark.parametrize("lib", ["torchrl", "sb3"])
def test_a_short_run_learns_to_drive_beyond_a_random_policy(tmp_path, lib):
    out = tmp_path / lib
    args = ["ppo", "--task", "platoon", "--lib", lib, "--controller", "direct", "--init-log-std=-0.7",
            "--scenarios", "adaptive:a01_straight_free", "--total-steps", "12288", "--envs", "4",
            "--frames-per-batch", "1024", "--minibatch-size", "256", "--epochs", "4", "--eval-every", "0",
            "--eval-suite", str(SUITE), "--eval-episodes", "2", "--out-dir", str(out), "--quiet"]  # fmt: skip
    assert main(args) == 0
    returns = _scalars(out / "tensorboard", "episode/return")
    assert len(returns) == 12  # one value per batch of 1024 steps
    # The mean episode return of the last two batches against the first two: from about -20..-30
    # (a wobbling, nearly parked car) to +25..+35 (driving behind the lead).
    first, last = returns[:2].mean(), returns[-2:].mean()
    assert last > first + 30.0, returns
    assert last > 10.0, returns
    # Held-out evaluation (the suite's seeds, never trained on) against the reference rows of the
    # same report: better than the random policy.
    report = json.loads((out / "eval" / "results.json").read_text())
    scores = {agent: entry["scores"]["overall"]["S_bench"] for agent, entry in report["agents"].items()}
    policy = scores.pop(next(a for a in scores if a.endswith("policy.pt")))
    assert policy > scores["zoo:random"] + 0.1, scores
    # The evaluation reached TensorBoard as the same number.
    assert _scalars(out / "tensorboard", "eval/S_bench")[-1] == pytest.approx(policy, abs=1e-6)
