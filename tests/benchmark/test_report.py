"""The benchmark report as a reader gets it: every figure embedded in report.md and readable, the
trajectory figures showing the lead and the traffic from the logs' scene, agents named by name,
and no zero-width interval printed as if it were certain."""

from __future__ import annotations

import csv
import json
import os
import re
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from smarts.benchmark.jobs import plan_jobs
from smarts.benchmark.report import REFERENCE_COLOURS, TRAFFIC_COLOUR, write_report
from smarts.benchmark.runner import run_jobs
from smarts.benchmark.suites import load_suite

TINY = str(Path(__file__).with_name("tiny_suite.yaml"))


def _colour(hex_colour: str) -> np.ndarray:
    return np.array([int(hex_colour[i : i + 2], 16) for i in (1, 3, 5)])


def pixels_near(image: np.ndarray, rgb: np.ndarray, tolerance: int = 12) -> int:
    return int((np.abs(image[..., :3].astype(int) - rgb).max(axis=-1) <= tolerance).sum())


@pytest.fixture(scope="module")
def adaptive_report(tmp_path_factory) -> Path:
    """The adaptive suite cut to a01 (empty road, a lead) and a09 (a signalised junction with
    traffic), one episode each: the reference agents only."""
    import yaml

    from smarts.core.resources import config_path

    out = tmp_path_factory.mktemp("report")
    data = yaml.safe_load(config_path("benchmark", "adaptive.yaml").read_text())
    data["scenarios"] = [s for s in data["scenarios"] if s["name"][:3] in ("a01", "a09")]
    (out / "two.yaml").write_text(yaml.safe_dump(data))  # jobs load their suite from its file
    suite = load_suite(out / "two.yaml")
    jobs = plan_jobs([], suite, 1, out)
    write_report(out, suite, [], run_jobs(jobs, workers=2, progress=False))
    return out


def test_every_figure_is_embedded_and_reads_back(adaptive_report):
    report = (adaptive_report / "report.md").read_text()
    embedded = re.findall(r"!\[([^\]]+)\]\((plots/[^)]+\.png)\)", report)
    on_disk = sorted(p.relative_to(adaptive_report).as_posix() for p in (adaptive_report / "plots").glob("*.png"))
    assert sorted(path for _, path in embedded) == on_disk
    assert {"plots/metric_S_bench.png", "plots/trajectories_a01_straight_free.png"} <= set(on_disk)
    for _, path in embedded:
        with Image.open(adaptive_report / path) as image:
            image.load()
            assert image.format == "PNG" and image.width >= 500 and image.height >= 250, path
    # Each scenario's figure sits under its own table.
    section = report.split("### a09_lead_turns_right_at_signal_medium")[1]
    assert section.index("| zoo:keep-lane (reference) |") < section.index("](plots/trajectories_a09")


def test_trajectory_figures_draw_the_lead_the_traffic_and_the_agents(adaptive_report, tmp_path):
    """The same report from the same logs without their scene: the lead's path (black) and the
    traffic's (blue) are what the scene adds."""
    from smarts.benchmark.metrics import read_episode, write_episode

    results = []
    for path in sorted((adaptive_report / "logs").rglob("*.npz")):
        log = read_episode(path)
        log.scene = None
        bare = tmp_path / "logs" / path.relative_to(adaptive_report / "logs")
        write_episode(log, bare)
        results.append({"agent": log.info["agent"], "scenario": log.scenario, "episode": log.episode,
                        "seed": log.seed, "failure": None, "log": str(bare)})  # fmt: skip
    write_report(tmp_path, load_suite(adaptive_report / "two.yaml"), [], results)

    def image(folder, scenario):
        return np.asarray(Image.open(folder / "plots" / f"trajectories_{scenario}.png").convert("RGB"))

    a01, a09 = "a01_straight_free", "a09_lead_turns_right_at_signal_medium"
    black, traffic = np.zeros(3), _colour(TRAFFIC_COLOUR)
    for scenario in (a01, a09):
        full, bare = image(adaptive_report, scenario), image(tmp_path, scenario)
        assert pixels_near(full, black, 40) > pixels_near(bare, black, 40) + 300, scenario  # the lead
        assert pixels_near(full, _colour(REFERENCE_COLOURS["zoo:keep-lane"])) > 200  # the agents
        assert pixels_near(full, _colour("#d5d5d8"), 3) > 2000  # the road surface
    assert pixels_near(image(adaptive_report, a09), traffic, 30) > pixels_near(image(tmp_path, a09), traffic, 30) + 100
    assert pixels_near(image(adaptive_report, a01), traffic, 30) < 20  # a01 is an empty road


def test_one_episode_gives_no_interval_and_says_so(adaptive_report):
    report = (adaptive_report / "report.md").read_text()
    assert "**Warning:** some intervals below are n/a" in report
    row = next(line for line in report.splitlines() if line.startswith("| zoo:keep-lane (reference) | relative"))
    assert row.count("[n/a]") == 5 and not re.search(r"\[\d\.\d{3}, \d\.\d{3}\]", row)
    doc = json.loads((adaptive_report / "results.json").read_text())
    scores = doc["agents"]["zoo:keep-lane"]["scores"]
    assert scores["overall_ci"]["S_bench"] is None and "null" in doc["ci"]
    rows = list(csv.DictReader((adaptive_report / "results.csv").open()))
    overall = next(r for r in rows if r["agent"] == "zoo:keep-lane" and r["scenario"] == "overall")
    assert overall["S_bench"] and overall["S_bench_ci_low"] == overall["S_bench_ci_high"] == ""


def test_episodes_that_differ_give_intervals(tmp_path):
    suite = load_suite(TINY)  # seeds 7 and 8: random drives differently in each
    jobs = plan_jobs(["zoo:random"], suite, 2, tmp_path, references=False)
    write_report(tmp_path, suite, ["zoo:random"], run_jobs(jobs, workers=1, progress=False))
    report = (tmp_path / "report.md").read_text()
    row = next(line for line in report.splitlines() if line.startswith("| zoo:random (reference) | relative"))
    low, high = map(float, re.findall(r"\[(\d\.\d{3}), (\d\.\d{3})\]", row)[-1])  # S_bench, the last column
    assert low < high  # (RC and MTE, alike in both episodes, are n/a in this row)
    doc = json.loads((tmp_path / "results.json").read_text())
    assert doc["agents"]["zoo:random"]["scores"]["overall_ci"]["S_bench"] == pytest.approx([low, high], abs=5e-4)


def test_figures_drawn_by_a_helper_process_are_the_figures_drawn_here(adaptive_report, tmp_path, monkeypatch, caplog):
    """Trajectory and metric figures are shared out to helper interpreters (the metric ones added
    after the first); what a helper draws is byte for byte what the report's own process draws,
    and a helper that fails leaves its share to it."""
    from dataclasses import replace

    import smarts.worker_processes as worker_processes
    from smarts.benchmark.metrics import read_episode
    from smarts.benchmark.report import FigureHelpers, _draw, _Drawing, _metric_figures, _score, _trajectory_figures

    # Fresh interpreters first (another test in this process may have started the fork server).
    monkeypatch.setattr(worker_processes, "_server_started", False)
    suite = load_suite(adaptive_report / "two.yaml")
    results = []
    for path in sorted((adaptive_report / "logs").rglob("*.npz")):
        log = read_episode(path)
        results.append({"agent": log.info["agent"], "scenario": log.scenario, "episode": log.episode, "log": str(path)})
    agents = ["zoo:keep-lane", "zoo:random"]
    figures = _trajectory_figures(tmp_path, suite, agents, results)
    scored = _score(suite, agents, results, 0.95, 200, 0)
    metrics = _metric_figures(tmp_path, suite, scored.scores, scored.names, str)
    assert len(figures) == 2 and len(metrics) == len(scored.names) >= 4
    here = tmp_path / "here"
    here.mkdir()
    expected = {f.key: _draw(replace(f, plots=here)) for f in [*figures, *metrics]}

    def draw(helpers) -> dict:
        drawing = _Drawing(figures, helpers=helpers)
        drawing.add(metrics)  # once the scores are known, as write_report does
        return drawing.result()

    drawn = draw(1)
    assert set(drawn) == set(expected)
    assert {"a01_straight_free", "a09_lead_turns_right_at_signal_medium", ("metric", "S_bench")} <= set(drawn)
    for name in drawn:
        assert drawn[name].parent == tmp_path
        assert drawn[name].read_bytes() == expected[name].read_bytes(), name
    for path in drawn.values():
        path.unlink()
    started = FigureHelpers(1)  # started ahead (as beside a benchmark's episodes), then given the figures
    drawn = draw(started)
    assert started.processes == [] and {name: p.read_bytes() for name, p in drawn.items()} == {
        name: p.read_bytes() for name, p in expected.items()
    }
    unused = FigureHelpers(2)
    unused.close()
    assert unused.processes == []
    for path in drawn.values():
        path.unlink()
    monkeypatch.setenv("PYTHONHOME", str(tmp_path / "no-python-here"))  # the helper cannot start
    with caplog.at_level("WARNING"):
        again = draw(1)
    assert "a figure helper failed" in caplog.text
    assert {name: p.read_bytes() for name, p in again.items()} == {name: p.read_bytes() for name, p in expected.items()}

    monkeypatch.delenv("PYTHONHOME")
    worker_processes.start_worker_server()  # as train benchmark does: the helpers come from its fork server
    forked = FigureHelpers(2)
    assert all(h.channel is not None for h in forked.processes)
    for path in again.values():
        path.unlink()
    drawn = draw(forked)
    assert {name: p.read_bytes() for name, p in drawn.items()} == {name: p.read_bytes() for name, p in expected.items()}
    for path in drawn.values():
        path.unlink()
    alone = FigureHelpers.for_figures(6)  # one per core from the fork server, the caller drawing none
    assert not alone.caller_draws and len(alone.processes) == min(os.cpu_count(), 2)
    drawn = draw(alone)
    assert {name: p.read_bytes() for name, p in drawn.items()} == {name: p.read_bytes() for name, p in expected.items()}
    unused = FigureHelpers(1)
    unused.close()
    assert unused.processes == []


def test_a_report_prepared_while_episodes_run_is_the_report(adaptive_report, tmp_path, monkeypatch):
    """``ReportAhead`` reads and scores the logs offered while the episodes run and hands a scenario's
    trajectory figure to the helpers once every agent's episode 0 of it is in; the report built
    with it is the report built from the files (results, report.md, every figure byte for byte).
    A log rewritten after it was offered is read as it is now, one that does not read back raises
    what ``read_episode`` raises, and a budget too small for a log leaves it to the report."""
    import shutil
    import threading
    import time

    import smarts.benchmark.report as report_module
    from smarts.benchmark.metrics import LogError, read_episode, score_episode
    from smarts.benchmark.report import FigureHelpers, ReportAhead

    scored_in = []

    def counted(log, params):
        scored_in.append(threading.current_thread().name)
        return score_episode(log, params)

    monkeypatch.setattr(report_module, "score_episode", counted)

    paths = sorted((adaptive_report / "logs").rglob("*.npz"))
    results = []
    for path in paths:
        log = read_episode(path)
        results.append({"agent": log.info["agent"], "scenario": log.scenario, "episode": log.episode,
                        "seed": log.seed, "log": str(path)})  # fmt: skip
    suite = load_suite(adaptive_report / "two.yaml")
    jobs = plan_jobs([], suite, 1, tmp_path / "plan")
    out = tmp_path / "ahead"
    ahead = ReportAhead(out, suite, [], jobs, FigureHelpers(1))
    for k, r in enumerate(results):
        ahead.offer(r)
        if k == 0:
            assert ahead.handed == []  # the other agents' episode 0 of that scenario is still to come
    ahead.offer({"agent": "zoo:random", "log": None})  # an episode without a log: nothing to read
    assert [f.scenario for f in ahead.handed] == ["a01_straight_free", "a09_lead_turns_right_at_signal_medium"]
    deadline = time.monotonic() + 60
    while len(ahead._scores) < len(paths) and time.monotonic() < deadline:  # as while the episodes run
        time.sleep(0.05)
    write_report(out, suite, [], results, ahead=ahead)
    assert (out / "results.json").read_text() == (adaptive_report / "results.json").read_text()
    assert (out / "report.md").read_text().replace(str(out), "<run>") == (
        adaptive_report / "report.md"
    ).read_text().replace(str(adaptive_report), "<run>")
    drawn = sorted(p.name for p in (out / "plots").glob("*.png"))
    assert drawn == sorted(p.name for p in (adaptive_report / "plots").glob("*.png"))
    for name in drawn:
        assert (out / "plots" / name).read_bytes() == (adaptive_report / "plots" / name).read_bytes(), name
    assert not ahead._thread.is_alive() and ahead._logs == {}  # every log was taken by the report
    assert scored_in == ["report-ahead"] * len(paths) and ahead._scores == {}  # each scored once, ahead
    hurried = ReportAhead(tmp_path / "hurried", suite, [], jobs)  # the report starts at once: it does the rest
    for r in results:
        hurried.offer(r)
    write_report(tmp_path / "hurried", suite, [], results, ahead=hurried)
    assert (tmp_path / "hurried" / "results.json").read_text() == (adaptive_report / "results.json").read_text()
    assert not hurried._thread.is_alive() and hurried._logs == {}

    first, second = tmp_path / "first.npz", tmp_path / "second.npz"
    shutil.copy(paths[0], first)
    second.write_bytes(b"not a log")
    ahead = ReportAhead(tmp_path / "more", suite, [], jobs)
    ahead.offer({"log": str(first)})
    ahead.offer({"log": str(second)})
    first.write_bytes(paths[1].read_bytes())  # its episode ran again (a dead worker): offered again
    ahead.offer({"log": str(first)})
    assert read_episode(paths[0]).scenario != read_episode(paths[1]).scenario
    assert ahead.read(first).scenario == read_episode(paths[1]).scenario
    with pytest.raises(LogError, match="not a readable .npz episode log"):
        ahead.read(second)

    # The re-run's offer arrives after the thread read the first file but before it reads again
    # (the report started meanwhile): the log in hand is stale and the file is read now.
    shutil.copy(paths[0], first)
    ahead = ReportAhead(tmp_path / "stale", suite, [], jobs)
    ahead.offer({"log": str(first)})
    deadline = time.monotonic() + 30
    while str(first) not in ahead._logs and time.monotonic() < deadline:
        time.sleep(0.01)
    assert str(first) in ahead._logs
    ahead._enough = True  # the thread takes nothing more
    first.write_bytes(paths[1].read_bytes())
    ahead.offer({"log": str(first)})
    assert ahead.read(first).scenario == read_episode(paths[1]).scenario

    small = ReportAhead(tmp_path / "small", suite, [], jobs, budget=paths[0].stat().st_size - 1)
    small.offer({"log": str(paths[0])})
    assert small.read(paths[0]).scenario == read_episode(paths[0]).scenario and small._logs == {}


def test_a_figure_handed_out_early_that_differs_from_the_reports_is_drawn_again(adaptive_report, tmp_path):
    """Should a figure handed to the helpers early not be the one the report builds (its
    results changed after), the report's own is drawn over it."""
    from smarts.benchmark.metrics import read_episode
    from smarts.benchmark.report import FigureHelpers, ReportAhead

    results = []
    for path in sorted((adaptive_report / "logs").rglob("*.npz")):
        log = read_episode(path)
        results.append({"agent": log.info["agent"], "scenario": log.scenario, "episode": log.episode,
                        "seed": log.seed, "log": str(path)})  # fmt: skip
    suite = load_suite(adaptive_report / "two.yaml")
    out = tmp_path / "out"
    ahead = ReportAhead(out, suite, [], plan_jobs([], suite, 1, tmp_path / "plan"), FigureHelpers(1))
    wrong = next(r for r in results if r["scenario"] == "a09_lead_turns_right_at_signal_medium")
    a01 = next(r for r in results if r["scenario"] == "a01_straight_free" and r["agent"] == wrong["agent"])
    for r in results:
        ahead.offer(replace_log(r, a01["log"]) if r is wrong else r)  # a09's figure gets an a01 path
    write_report(out, suite, [], results, ahead=ahead)
    name = "trajectories_a09_lead_turns_right_at_signal_medium.png"
    assert (out / "plots" / name).read_bytes() == (adaptive_report / "plots" / name).read_bytes()


def replace_log(result: dict, log: str) -> dict:
    return {**result, "log": log}
