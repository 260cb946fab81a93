"""Benchmark suites, the runner and the report, end to end on real scenarios."""

import dataclasses
import json
from pathlib import Path

import numpy as np
import pytest

import zoo.registry
from smarts.benchmark.agents import REFERENCE_AGENTS, PolicySetup, load_policy, policy_setup, scenario_for
from smarts.benchmark.jobs import plan_jobs
from smarts.benchmark.metrics import read_episode
from smarts.benchmark.report import write_report
from smarts.benchmark.runner import build_env, run_jobs
from smarts.benchmark.suites import load_suite
from smarts.core.errors import AgentSetupError
from smarts.scenario import ScenarioError, replace
from train.__main__ import main

TINY = str(Path(__file__).with_name("tiny_suite.yaml"))


def test_collaborative_suite_covers_the_required_variety():
    suite = load_suite("collaborative")
    assert suite.task == "collaborative" and len(suite.scenarios) >= 12
    maps = {s.spec.map for s in suite.scenarios}
    assert any("t_junction" in m for m in maps) and any("4way" in m for m in maps)
    assert {1, 2, 3} <= {int(m.split("_")[2][0]) for m in maps if "4way" in m}  # lanes per approach
    assert any(m.endswith("_signal") for m in maps) and any(not m.endswith("_signal") for m in maps)
    assert {len(s.spec.agents) for s in suite.scenarios} == {1, 2, 3, 4}
    densities = {s.spec.traffic.density if s.spec.traffic else "none" for s in suite.scenarios}
    assert densities == {"none", "low", "medium", "high"}
    goals = {
        (a.mission.start.road.split("_")[0], a.mission.goal.road.split("_")[0])
        for s in suite.scenarios
        for a in s.spec.agents
    }
    assert any(a == b for a, b in goals)  # a U-turn
    assert {s.difficulty for s in suite.scenarios} == {"easy", "medium", "hard"}


def test_adaptive_suite_follows_leads_with_unknown_intentions():
    suite = load_suite("adaptive")
    assert suite.task == "adaptive" and len(suite.scenarios) >= 10
    assert all(s.follow for s in suite.scenarios)
    assert {len(s.follow) for s in suite.scenarios} == {1, 2, 3}
    assert all(a.mission.goal.endless for s in suite.scenarios for a in s.spec.agents)  # no hint of the lead's plan
    routes = {tuple(t.roads) for s in suite.scenarios for t in s.spec.traffic.trips if t.id == "lead"}
    assert ("main_0", "exit") in routes and ("ramp", "main_4") in routes and ("west_in", "north_out") in routes
    densities = {s.spec.traffic.density for s in suite.scenarios}
    assert {"none", "high"} <= densities


def test_bad_suite_files_name_the_field(tmp_path):
    bad = tmp_path / "bad.yaml"
    bad.write_text("task: collaborative\nscenarios:\n  - {name: x, difficulty: extreme, time_limit: 5, scenario: {}}\n")
    with pytest.raises(ScenarioError, match=r"bad.yaml: scenarios\[0\].difficulty"):
        load_suite(bad)
    with pytest.raises(ValueError, match="unknown benchmark suite 'nope'"):
        load_suite("nope")
    bad.write_text("task: adaptive\nepisodes: 0\nscenarioz: []\n")
    with pytest.raises(ScenarioError) as err:
        load_suite(bad)
    lines = str(err.value).splitlines()  # every problem, each with the file and the field
    assert any(line.startswith(f"{bad}: episodes: input should be greater than or equal to 1") for line in lines)
    assert any("scenarioz: unknown field; did you mean 'scenarios'?" in line for line in lines)
    assert any(line.endswith("scenarios: required field missing") for line in lines)


def _run(out, *extra):
    return main(["benchmark", "--suite", TINY, "--workers", "1", "--quiet", "--out", str(out), *extra])


def test_runner_writes_logs_results_report_plots_and_tensorboard(tmp_path, capsys):
    assert _run(tmp_path / "a", "--agent", "zoo:keep-lane", "--agent", "zoo:random") == 0
    out = tmp_path / "a"
    logs = sorted((out / "logs").rglob("*.npz"))
    assert len(logs) == 3 * 2 * 2  # agents (stand-still added as a reference) x scenarios x episodes
    log = read_episode(logs[0])
    assert log.task == "collaborative" and log.agents
    assert log.info["action_space"] == "relative_target_pose" and log.info["controller"] == "direct"
    results = json.loads((out / "results.json").read_text())
    keep, rand = (results["agents"][a]["scores"]["overall"] for a in ("zoo:keep-lane", "zoo:random"))
    assert 0.0 <= rand["S_bench"] < keep["S_bench"] <= 1.0
    assert results["references"] == ["zoo:stand-still"]
    assert results["seeds"] == {"t1_left": {"0": 7, "1": 8}, "t2_straight_traffic": {"0": 7, "1": 8}}
    report = (out / "report.md").read_text()
    assert "| zoo:keep-lane (reference) | relative_target_pose | direct |" in report and "S_bench" in report
    assert "| zoo:stand-still (reference) |" in report and "bootstrap" in report
    assert "| t1_left | easy | 4 | 0=7, 1=8 | none |" in report
    assert (out / "results.csv").read_text().count("overall") == 3
    assert (out / "plots" / "metric_S_bench.png").stat().st_size > 1000
    assert (out / "plots" / "trajectories_t1_left.png").stat().st_size > 1000
    assert list((out / "tensorboard").rglob("events.out.tfevents.*"))
    from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

    (folder,) = [p for p in (out / "tensorboard").iterdir() if "keep-lane" in p.name]
    board = EventAccumulator(str(folder)).Reload()
    (tag,) = [t for t in board.Tags()["scalars"] if t.endswith("/S_bench")]
    assert board.Scalars(tag)[0].value == pytest.approx(keep["S_bench"], rel=1e-6)  # float32 in the event
    # Same seed, same results.
    assert _run(tmp_path / "b", "--agent", "zoo:keep-lane", "--agent", "zoo:random") == 0
    again = json.loads((tmp_path / "b" / "results.json").read_text())
    assert _scores(again) == _scores(results)


def _scores(doc):
    return {a: v["scores"]["overall"] for a, v in doc["agents"].items()}


def test_failing_agents_are_recorded_and_the_suite_goes_on(tmp_path, monkeypatch):
    monkeypatch.setitem(zoo.registry.ZOO, "raising", ("tests.benchmark.broken_agent", "RaisingPolicy", ""))
    monkeypatch.setitem(zoo.registry.ZOO, "nan", ("tests.benchmark.broken_agent", "NaNPolicy", ""))
    assert _run(tmp_path, "--agent", "zoo:raising", "--agent", "zoo:nan", "--agent", "zoo:keep-lane") == 0
    results = json.loads((tmp_path / "results.json").read_text())
    raising = results["agents"]["zoo:raising"]["scores"]
    assert len(raising["failed"]) == 4 and "planner crashed" in raising["failed"][0]["failure"]
    assert raising["overall"]["S_bench"] == 0.0
    nan = results["agents"]["zoo:nan"]["scores"]["failed"]
    assert "is nan" in nan[0]["failure"] and "agent_0" in nan[0]["failure"]
    assert results["agents"]["zoo:keep-lane"]["scores"]["overall"]["S_bench"] > 0.3
    assert "Failed episodes" in (tmp_path / "report.md").read_text()


def test_unknown_agent_or_suite_is_a_clear_cli_error(tmp_path, capsys):
    assert _run(tmp_path, "--agent", "zoo:nobody") == 2
    assert "unknown agent locator 'zoo:nobody'" in capsys.readouterr().err
    assert main(["benchmark", "--suite", "nonexistent", "--quiet", "--out", str(tmp_path)]) == 2
    assert "unknown benchmark suite" in capsys.readouterr().err


@pytest.fixture
def space_agents(monkeypatch):
    for name, cls in (("throttle", "ThrottlePolicy"), ("lane-model", "LanePolicy"),
                      ("extended-ego", "ExtendedEgoPolicy"), ("bad-controller", "BadControllerPolicy")):  # fmt: skip
        monkeypatch.setitem(zoo.registry.ZOO, name, ("tests.benchmark.space_agents", cls, ""))


def test_a_continuous_policy_drives_a_continuous_vehicle(tmp_path, space_agents):
    suite = load_suite(TINY)
    setup = policy_setup(load_policy("zoo:throttle"), "zoo:throttle")
    assert setup == PolicySetup("continuous", "direct", None)
    env = build_env(suite.scenarios[1], setup)
    try:
        assert [a.action_space for a in env.scenario.agents] == ["continuous", "continuous"]
        assert env.action_space("agent_0").shape == (3,)
    finally:
        env.close()
    jobs = plan_jobs(["zoo:throttle"], suite, 1, tmp_path, references=False)
    assert [j.agent for j in jobs] == ["zoo:throttle"] * 2
    results = run_jobs(jobs, workers=1, progress=False)
    assert [r["failure"] for r in results] == [None, None]
    assert {(r["action_space"], r["controller"]) for r in results} == {("continuous", "direct")}
    log = read_episode(results[1]["log"])
    assert log.info["action_space"] == "continuous" and log.info["agent"] == "zoo:throttle"
    trace = log.agents["agent_0"]
    # Throttle 0.6 on the pybullet car speeds it up from its 8 m/s start; read as a relative pose
    # (0.6 m forward per 0.1 s step) the same numbers would brake it towards 6 m/s.
    assert trace.speed[-1] > 8.5 and (np.diff(trace.speed) > 0).mean() > 0.8


def test_a_policy_in_an_action_space_the_suite_does_not_host_is_refused_before_any_episode(
    tmp_path, capsys, space_agents
):
    assert _run(tmp_path / "a", "--agent", "zoo:lane-model") == 2
    err = capsys.readouterr().err
    assert "agent 'zoo:lane-model' acts in action space 'lane'" in err
    assert "hosted: relative_target_pose, target_pose, continuous" in err
    assert not (tmp_path / "a").exists()  # no episode ran
    suite = load_suite(TINY)
    narrow = dataclasses.replace(suite, action_spaces=("relative_target_pose",))
    with pytest.raises(AgentSetupError, match=r"'continuous' .*hosted: relative_target_pose$"):
        plan_jobs(["zoo:throttle"], narrow, 1, tmp_path / "b")
    with pytest.raises(AgentSetupError, match="controller 'telepathy'"):
        plan_jobs(["zoo:bad-controller"], suite, 1, tmp_path / "b")
    # A suite may host the lane model by saying so.
    lane_suite = tmp_path / "lane.yaml"
    lane_suite.write_text(Path(TINY).read_text().replace("episodes: 2", "episodes: 2\naction_spaces: [lane]"))
    assert load_suite(lane_suite).action_spaces == ("lane",)
    assert len(plan_jobs(["zoo:lane-model"], load_suite(lane_suite), 1, tmp_path / "c", references=False)) == 2
    bad = tmp_path / "bad.yaml"
    bad.write_text(Path(TINY).read_text().replace("episodes: 2", "episodes: 2\naction_spaces: [warp]"))
    with pytest.raises(ScenarioError, match="bad.yaml: action_spaces"):
        load_suite(bad)


def test_the_runner_observes_with_the_policy_interface(tmp_path, space_agents):
    jobs = plan_jobs(["zoo:extended-ego"], load_suite(TINY), 1, tmp_path, references=False)
    results = run_jobs(jobs, workers=1, progress=False)
    assert [r["failure"] for r in results] == [None, None]
    assert read_episode(results[0]["log"]).info["interface"] == {"ego": {"extended": True}}


def test_reference_agents_are_added_and_can_be_cached(tmp_path):
    suite = load_suite(TINY)
    cache = tmp_path / "cache"
    jobs = plan_jobs(["zoo:keep-lane"], suite, 1, tmp_path / "a", reference_cache=cache)
    assert [j.agent for j in jobs[::2]] == list(REFERENCE_AGENTS)
    assert [j.seed for j in jobs] == [7] * 6
    cached = [Path(j.log_path) for j in jobs if j.reuse]
    assert len(cached) == 6 and all(cache in p.parents for p in cached)  # every reference agent's episodes
    first = run_jobs(jobs, workers=1, progress=False)
    stamps = [p.stat().st_mtime_ns for p in cached]
    again = run_jobs(
        plan_jobs(["zoo:keep-lane"], suite, 1, tmp_path / "b", reference_cache=cache), workers=1, progress=False
    )
    assert [p.stat().st_mtime_ns for p in cached] == stamps  # reused, not re-run
    assert [r["log"] for r in again] == [str(p) for p in cached]
    write_report(tmp_path / "b", suite, ["zoo:keep-lane"], again)
    doc = json.loads((tmp_path / "b" / "results.json").read_text())
    assert doc["references"] == ["zoo:random", "zoo:stand-still"]
    assert all(doc["agents"][a]["reference"] for a in REFERENCE_AGENTS)
    assert first[0]["failure"] is None


def test_only_learning_agents_take_the_policy_action_space_and_controller():
    spec = load_suite(TINY).scenarios[1].spec
    social = replace(spec.agents[1], policy="zoo:keep-lane")
    spec = replace(spec, agents=[spec.agents[0], social])
    built = scenario_for(spec, PolicySetup("target_pose", "lane_relative"))
    assert (built.agents[0].action_space, built.agents[0].controller) == ("target_pose", "lane_relative")
    assert (built.agents[1].action_space, built.agents[1].controller) == ("relative_target_pose", "direct")
    assert spec.agents[0].action_space == "relative_target_pose"  # the suite's spec is not changed


def test_a_checkpoint_evaluates_like_train_ppo_does(tmp_path):
    # The call sequence of train.ppo.evaluate_into: plan_jobs, run_jobs, write_report.
    frozen = tmp_path / "policy.pt"
    frozen.write_bytes((Path(zoo.registry.ZOO_DIR) / "checkpoints" / "platoon-c.pt").read_bytes())
    suite = load_suite(TINY)
    jobs = plan_jobs([str(frozen)], suite, 1, tmp_path)
    results = run_jobs(jobs, workers=2, progress=False)
    write_report(tmp_path, suite, [str(frozen)], results)
    doc = json.loads((tmp_path / "results.json").read_text())
    mine = doc["agents"][str(frozen)]
    assert mine["action_space"] == "continuous" and mine["scores"]["overall"]["S_bench"] >= 0.0
    assert doc["references"] == list(REFERENCE_AGENTS)


@pytest.mark.parametrize(
    "section, value, problem",
    [
        (
            "interface",
            {"lidar": {"rays": 0}},
            "recorded observation interface is invalid (interface.lidar.rays: input should be greater than or equal to 1",
        ),
        ("interface", ["lead"], "recorded observation interface is invalid (interface: expected a mapping"),
        (
            "lane_relative",
            {"max_jerk": -1.0},
            "recorded lane-relative settings are invalid (LaneRelativeParams.max_jerk:",
        ),
        (
            "lane_relative",
            {"max_jerks": 1.0},
            "recorded lane-relative settings are invalid (lane_relative.max_jerks: unknown",
        ),
    ],
)
def test_a_checkpoint_with_bad_recorded_settings_is_refused_before_any_episode(
    tmp_path, capsys, section, value, problem
):
    """The policy carries its settings as plain data; the runner validates them (and `train eval`
    exits with the file and the field) before any episode runs."""
    import torch

    blob = torch.load(Path(zoo.registry.ZOO_DIR) / "checkpoints" / "platoon-c.pt", weights_only=True)
    blob[section] = value
    bad = tmp_path / "bad.pt"
    torch.save(blob, bad)
    with pytest.raises(AgentSetupError) as raised:
        plan_jobs([str(bad)], load_suite(TINY), 1, tmp_path / "a")
    assert str(raised.value).startswith(f"agent {str(bad)!r}: {problem}")
    out = tmp_path / "eval"
    assert main(["eval", "--agent", str(bad), "--suite", TINY, "--episodes", "1", "--workers", "1", "--quiet",
                 "--out", str(out)]) == 2  # fmt: skip
    assert f"{bad}': {problem}" in capsys.readouterr().err and not out.exists()
