"""Benchmark suites, the runner and the report, end to end on real scenarios."""

import json
from pathlib import Path

import pytest

import zoo.registry
from smarts.benchmark.metrics import read_episode
from smarts.benchmark.suites import load_suite
from smarts.scenario import ScenarioError
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
    goals = {(a.mission.start.road.split("_")[0], a.mission.goal.road.split("_")[0]) for s in suite.scenarios for a in s.spec.agents}
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


def _run(out, *extra):
    return main(["benchmark", "--suite", TINY, "--workers", "1", "--quiet", "--out", str(out), *extra])


def test_runner_writes_logs_results_report_plots_and_tensorboard(tmp_path, capsys):
    assert _run(tmp_path / "a", "--agent", "zoo:keep-lane", "--agent", "zoo:random") == 0
    out = tmp_path / "a"
    logs = sorted((out / "logs").rglob("*.npz"))
    assert len(logs) == 2 * 2 * 2  # agents x scenarios x episodes
    log = read_episode(logs[0])
    assert log.task == "collaborative" and log.agents
    results = json.loads((out / "results.json").read_text())
    keep, rand = (results["agents"][a]["scores"]["overall"] for a in ("zoo:keep-lane", "zoo:random"))
    assert 0.0 <= rand["S_bench"] < keep["S_bench"] <= 1.0
    report = (out / "report.md").read_text()
    assert "| zoo:keep-lane |" in report and "S_bench" in report
    assert (out / "results.csv").read_text().count("overall") == 2
    assert (out / "plots" / "metric_S_bench.png").stat().st_size > 1000
    assert (out / "plots" / "trajectories_t1_left.png").stat().st_size > 1000
    assert list((out / "tensorboard").rglob("events.out.tfevents.*"))
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
