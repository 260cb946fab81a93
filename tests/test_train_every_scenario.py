"""Every suite scenario and every built-in (README) scenario trains on the batched core, with the
default observation and with every sensor and V2V on, and the checkpoint is then benchmarked on
each of them in the settings it was trained with (short time limits keep the test quick)."""

from pathlib import Path

import pytest
import torch
import yaml

from smarts.benchmark.jobs import Job
from smarts.benchmark.runner import run_episode
from smarts.benchmark.suites import SUITES_DIR
from smarts.scenario import list_scenarios
from smarts.scenario.library import scenario_path
from train.__main__ import main

ALL_SENSORS = ("{neighbours: {extended: true}, occlusion: {enabled: true, mode: hide}, lidar: {rays: 16, range: 30}, "
               "rasters: {size: 16, resolution: 1.0, layers: [drivable, lanes, route, occupancy, occlusion], rgb: true}}")  # fmt: skip
V2V = "{range: 60, latency: 1, loss: 0.05, message_size: 4, max_messages: 4, penetration: 0.5}"
SUITE_OF = {"platoon": "adaptive", "drive": "collaborative"}


def short_suite(tmp_path: Path, task: str, v2v: bool | None = None) -> Path:
    """The task's suite with 1 s episodes; the drive suite also holds every built-in scenario.
    ``v2v``: only the scenarios with (True) or without (False) their own comms section."""
    suite = yaml.safe_load((SUITES_DIR / f"{SUITE_OF[task]}.yaml").read_text())
    if task == "drive":
        for name in list_scenarios():
            spec = yaml.safe_load(scenario_path(name).read_text())
            suite["scenarios"].append({"name": name, "difficulty": "easy", "time_limit": 1.0, "scenario": spec})
    if v2v is not None:
        suite["scenarios"] = [e for e in suite["scenarios"] if ("comms" in e["scenario"]) == v2v]
    for entry in suite["scenarios"]:
        entry["time_limit"] = 1.0
    path = tmp_path / f"short_{task}_{v2v}.yaml"
    path.write_text(yaml.safe_dump(suite))
    return path


def train_and_benchmark(tmp_path: Path, task: str, suite: Path, options: list[str]) -> dict:
    """One batch of training on every scenario of ``suite``, then an episode of each driven by
    the checkpoint; the checkpoint's contents."""
    names = [s["name"] for s in yaml.safe_load(suite.read_text())["scenarios"]]
    out = tmp_path / suite.stem
    code = main(["ppo", "--task", task, "--suite", str(suite), "--envs", str(len(names)), "--workers", "0",
                 "--total-steps", "64", "--frames-per-batch", "64", "--minibatch-size", "32", "--epochs", "1",
                 "--eval-episodes", "0", "--out-dir", str(out), "--quiet", *options])  # fmt: skip
    assert code == 0
    # The checkpoint drives every scenario in the settings it was trained with.
    for index, name in enumerate(names):
        job = Job(str(out / "final.pt"), str(suite), index, 0, 7, str(out / "logs" / f"{name}.npz"))
        result = run_episode(job)
        assert result["failure"] is None, (name, result["failure"])
        assert result["scenario"] == name
    return torch.load(out / "final.pt", weights_only=True)


@pytest.mark.parametrize("task", ["platoon", "drive"])
def test_every_scenario_trains_and_is_benchmarked_with_all_sensors_and_v2v(tmp_path, task):
    blob = train_and_benchmark(
        tmp_path, task, short_suite(tmp_path, task), ["--interface", ALL_SENSORS, "--comms", V2V]
    )
    assert blob["comms"]["message_size"] == 4 and blob["interface"]["lidar"]["rays"] == 16
    keys = set(blob["layout"]["keys"])
    assert {"messages", "message_mask"} <= keys and len(blob["action"]["low"]) == 2 + 4  # commands, then payload


@pytest.mark.parametrize("task", ["platoon", "drive"])
def test_every_scenario_trains_and_is_benchmarked_with_the_default_observation(tmp_path, task, capsys):
    if task == "drive":  # a scenario with its own V2V observes messages: it cannot share a policy with the others
        mixed = short_suite(tmp_path, task)
        assert main(["ppo", "--task", task, "--suite", str(mixed), "--envs", "27", "--total-steps", "64",
                     "--eval-episodes", "0", "--out-dir", str(tmp_path / "mixed"), "--quiet"]) == 2  # fmt: skip
        assert "message_mask, messages only in this one" in capsys.readouterr().err
        blob = train_and_benchmark(tmp_path, task, short_suite(tmp_path, task, v2v=True), [])
        assert blob["comms"] is None and "messages" in blob["layout"]["keys"]  # the scenario's own V2V
    blob = train_and_benchmark(tmp_path, task, short_suite(tmp_path, task, v2v=False if task == "drive" else None), [])
    assert blob["comms"] is None and "messages" not in blob["layout"]["keys"]
