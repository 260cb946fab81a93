"""`python -m train ppo --backend batched` trains as the per-env path does on the same budget."""

import json

import pytest
import torch

from train.__main__ import main


def _train(tmp_path, capsys, backend: str, lib: str = "torchrl") -> tuple[dict, dict]:
    """(final checkpoint, printed summary with the held-out evaluation) of a short run."""
    out = tmp_path / backend
    args = ["ppo", "--task", "platoon", "--lib", lib, "--backend", backend, "--total-steps", "1536",
            "--frames-per-batch", "512", "--minibatch-size", "128", "--epochs", "2", "--envs", "4",
            "--eval-episodes", "1", "--eval-workers", "1",
            "--scenarios", "adaptive:a01_straight_free,adaptive:a02_straight_two_followers_low,adaptive:a08_lead_turns_left_at_junction",
            "--out-dir", str(out), "--quiet"]  # fmt: skip
    capsys.readouterr()
    assert main(args) == 0
    printed = capsys.readouterr().out
    summary = json.loads(printed[printed.index("{\n"):printed.rindex("}") + 1])
    return torch.load(out / "final.pt", weights_only=True), summary


@pytest.mark.parametrize("lib", ["torchrl", "sb3"])
def test_a_short_run_matches_the_per_env_path(tmp_path, capsys, lib):
    """Both backends play the same episodes (same seeds, same dynamics), so the same short run
    gives the same training metrics and the same held-out benchmark score; a loose bound would
    hide a backend that drifts, so the check is equality up to float noise."""
    (per_env, a), (batched, b) = _train(tmp_path, capsys, "per_env", lib), _train(tmp_path, capsys, "batched", lib)
    assert per_env["step"] == batched["step"] >= 1536
    compared = [k for k in a if k.startswith(("episode/", "eval/", "loss/")) and a[k] is not None]
    assert any(k.startswith("eval/") for k in compared) and any(k.startswith("episode/") for k in compared)
    for key in compared:
        assert b[key] == pytest.approx(a[key], rel=1e-4, abs=1e-4), key
