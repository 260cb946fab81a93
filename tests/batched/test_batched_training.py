"""`python -m train ppo`: both backends build the one batched env, so a run trains the same whether
its copies are stepped in this process or spread over worker processes."""

import json
from pathlib import Path

import pytest
import torch

from train.__main__ import main

TINY = str(Path(__file__).parents[1] / "benchmark" / "tiny_suite.yaml")


def _train(tmp_path, capsys, backend: str, workers: int, lib: str = "torchrl") -> tuple[dict, dict]:
    """(final checkpoint, printed summary with the held-out evaluation) of a short run."""
    out = tmp_path / backend
    args = ["ppo", "--task", "platoon", "--lib", lib, "--backend", backend, "--workers", str(workers), "--total-steps", "1536",
            "--frames-per-batch", "512", "--minibatch-size", "128", "--epochs", "2", "--envs", "4",
            "--eval-episodes", "1", "--eval-workers", "1", "--eval-suite", TINY,
            "--scenarios", "adaptive:a01_straight_free,adaptive:a02_straight_two_followers_low,adaptive:a08_lead_turns_left_at_junction",
            "--out-dir", str(out), "--quiet"]  # fmt: skip
    capsys.readouterr()
    assert main(args) == 0
    printed = capsys.readouterr().out
    summary = json.loads(printed[printed.index("{\n") : printed.rindex("}") + 1])
    return torch.load(out / "final.pt", weights_only=True), summary


@pytest.mark.parametrize("lib", ["torchrl", "sb3"])
def test_a_short_run_is_the_same_in_this_process_and_over_workers(tmp_path, capsys, lib):
    """per_env in this process against batched over two worker processes (shares of two and three
    learning agents): the same episodes (same seeds, same dynamics), so the same short run gives
    the same training metrics and the same held-out benchmark score; a loose bound would hide a
    split that drifts, so the check is equality up to float noise."""
    (here, a), (split, b) = _train(tmp_path, capsys, "per_env", 1, lib), _train(tmp_path, capsys, "batched", 2, lib)
    assert here["step"] == split["step"] >= 1536
    assert (here["config"]["backend"], split["config"]["workers"]) == ("per_env", 2)
    compared = [k for k in a if k.startswith(("episode/", "eval/", "loss/")) and a[k] is not None]
    assert any(k.startswith("eval/") for k in compared) and any(k.startswith("episode/") for k in compared)
    for key in compared:
        assert b[key] == pytest.approx(a[key], rel=1e-4, abs=1e-4), key
