"""Ray scale-out: benchmark episodes as Ray tasks and PPO collectors as Ray actors, on a local
Ray instance, give the same results as the process-pool path and a usable checkpoint."""

import json
from pathlib import Path

import pytest
import torch

from train.__main__ import main

pytest.importorskip("ray", reason="ray is not installed: pip install 'smarts[ray]' to run the Ray scale-out tests")

TINY = str(Path(__file__).parent / "benchmark" / "tiny_suite.yaml")


def _overall(out: Path) -> dict:
    return json.loads((out / "results.json").read_text())["agents"]["zoo:keep-lane"]["scores"]["overall"]


def test_benchmark_on_ray_scores_the_same_as_the_process_pool(tmp_path):
    base = ["benchmark", "--suite", TINY, "--episodes", "1", "--agent", "zoo:keep-lane", "--quiet"]
    assert main([*base, "--workers", "2", "--out", str(tmp_path / "pool")]) == 0
    assert main([*base, "--ray-address", "local", "--out", str(tmp_path / "ray")]) == 0
    assert len(list((tmp_path / "ray" / "logs" / "zoo_keep-lane").rglob("*.npz"))) == 2  # one episode per scenario
    assert len(list((tmp_path / "ray" / "logs").rglob("*.npz"))) == 3 * 2  # with the other reference agents
    pool, ray = _overall(tmp_path / "pool"), _overall(tmp_path / "ray")
    assert pool and ray == pool


def test_ppo_with_ray_collectors_writes_a_final_checkpoint(tmp_path):
    out = tmp_path / "run"
    args = ["ppo", "--task", "platoon", "--total-steps", "256", "--frames-per-batch", "128", "--minibatch-size", "64",
            "--epochs", "1", "--envs", "2", "--workers", "2", "--eval-episodes", "0", "--ray-address", "local",
            "--out-dir", str(out), "--quiet"]  # fmt: skip
    assert main(args) == 0
    blob = torch.load(out / "final.pt", weights_only=True)
    assert blob["step"] == 256 and blob["config"]["ray_address"] == "local"


def test_ray_collectors_need_envs_divisible_by_workers(tmp_path, capsys):
    args = ["ppo", "--task", "platoon", "--envs", "3", "--workers", "2", "--ray-address", "local",
            "--out-dir", str(tmp_path), "--quiet"]  # fmt: skip
    assert main(args) == 2
    assert "must be multiples of workers" in capsys.readouterr().err
