"""The learned parts' commands end to end on a tiny suite: data, training, weights-only checkpoints,
TensorBoard logs, and the trained nets driving through the zoo's factories."""

import json

import numpy as np
import pytest
import yaml

from agents.checkpoint import CheckpointError
from agents.planners.nets import load_net
from smarts.benchmark.suites import SUITES_DIR
from train.__main__ import main as train_main


@pytest.fixture(scope="module")
def tiny_suite(tmp_path_factory):
    """Two collaborative scenarios with traffic, cut to 4 s."""
    folder = tmp_path_factory.mktemp("tiny")
    suite = yaml.safe_load((SUITES_DIR / "collaborative.yaml").read_text())
    suite["scenarios"] = [{**suite["scenarios"][i], "time_limit": 4} for i in (1, 2)]
    path = folder / "tiny.yaml"
    path.write_text(yaml.safe_dump(suite))
    return path


def test_trajectories_then_aid_predictor(tiny_suite, tmp_path):
    data = tmp_path / "data"
    assert train_main(["trajectories", "--suite", str(tiny_suite), "--seeds", "2", "--out", str(data), "--quiet"]) == 0
    episode = np.load(data / "c02_4way_1lane_right_low.npz")["seed0"]
    assert episode.shape[0] == 41 and episode.shape[2] == 7 and episode[..., 6].any()
    out = tmp_path / "aid"
    args = ["aid-predictor", "--data", str(data), "--out", str(out), "--steps", "6", "--eval-every", "3",
            "--per-episode", "20", "--quiet"]  # fmt: skip
    assert train_main(args) == 0
    net, metrics = load_net(out / "best.pt", "aid-predictor")
    assert {"fde", "cv_fde", "accepted", "minutes"} <= set(metrics)
    assert list((out / "tensorboard").glob("events.out.tfevents.*"))
    with pytest.raises(CheckpointError, match="kind 'tf-stop-move'"):
        load_net(out / "best.pt", "tf-stop-move")
    from zoo.planners import aid

    _drive(aid(out / "best.pt"))


def test_tf_bc_and_vcr_classifier(tiny_suite, tmp_path):
    assert train_main(["tf-bc", "--suite", str(tiny_suite), "--seeds", "1", "--steps", "5", "--situations", "20",
                       "--situation-steps", "30", "--out", str(tmp_path / "tf"), "--quiet"]) == 0  # fmt: skip
    summary = json.loads((tmp_path / "tf" / "summary.json").read_text())
    assert summary["train_samples"] > 0 and summary["train_stops"] > 0
    assert 0.0 <= summary["suites/accuracy"] <= 1.0 and 0.0 <= summary["situations/accuracy"] <= 1.0
    assert train_main(["vcr-classifier", "--suite", str(tiny_suite), "--seeds", "1", "--epochs", "1", "--situations", "20",
                       "--situation-steps", "30", "--out", str(tmp_path / "vcr"), "--quiet"]) == 0  # fmt: skip
    summary = json.loads((tmp_path / "vcr" / "summary.json").read_text())
    assert summary["train_classes"]["collision"] > 0 and "situations/collision_recall" in summary
    from zoo.planners import tf, vcr

    _drive(tf(tmp_path / "tf" / "final.pt"))
    _drive(vcr(tmp_path / "vcr" / "final.pt"))


def _drive(policy, steps: int = 30):
    """A few steps of a collaborative scenario through the benchmark's env for this policy."""
    from smarts.benchmark.agents import policy_setup
    from smarts.benchmark.runner import build_env
    from smarts.benchmark.suites import load_suite

    entry = load_suite("collaborative").scenarios[0]
    env = build_env(entry, policy_setup(policy, "test"))
    obs, _ = env.reset(seed=0)
    for _ in range(steps):
        batch = {k: np.stack([obs[a][k] for a in env.agents]) for k in obs[env.agents[0]]}
        actions = policy.act(batch)
        assert actions.shape == (len(env.agents), 3) and np.isfinite(actions).all()
        obs, *_ = env.step(dict(zip(env.agents, actions)))
    env.close()
