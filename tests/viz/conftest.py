"""Episodes for the viewer tests: a recording of a signalised intersection with built-in traffic
(cut at 150 steps) and a benchmark log written by the benchmark runner."""

from __future__ import annotations

from pathlib import Path

import pytest

SCENARIO = "intersection_4way_signal_traffic"  # signals and built-in traffic
STEPS = 150


def drive(env, steps: int | None = None) -> int:
    """The README's policy: 40% of the way to the waypoint 2 m ahead; returns the steps taken."""
    obs, _ = env.reset(seed=0)
    n = 0
    while env.agents and (steps is None or n < steps):
        obs, *_ = env.step({a: 0.4 * obs[a]["waypoints"][0, 1] for a in env.agents})
        n += 1
    return n


@pytest.fixture(scope="session")
def recorded(tmp_path_factory) -> dict:
    """One recorded episode with built-in traffic, and what the simulator
    held at every step (vehicle id -> x, y, speed), read by a listener of its own."""
    from smarts.env import DrivingParallelEnv
    from smarts.viz.watch import WatchedEnv

    folder = tmp_path_factory.mktemp("recordings")
    env = WatchedEnv(DrivingParallelEnv(SCENARIO), record=folder)
    seen = {}
    env.env.add_step_listener(lambda sim: seen.setdefault(
        int(round(sim.time / sim.dt)),
        {sim.table.ids[r]: (float(sim.table.x[r]), float(sim.table.y[r]), float(sim.table.speed[r]))
         for r in sim.table.alive_rows},
    ))  # fmt: skip
    steps = drive(env, STEPS)
    env.close()
    (path,) = env.recordings
    return {"path": Path(path), "folder": folder, "steps": steps, "truth": seen, "agents": list(env.possible_agents)}


@pytest.fixture(scope="session")
def benchmark_log(tmp_path_factory) -> Path:
    """One adaptive-suite episode of zoo:keep-lane, written by the benchmark runner."""
    from smarts.benchmark.jobs import plan_jobs
    from smarts.benchmark.runner import run_jobs
    from smarts.benchmark.suites import load_suite

    out = tmp_path_factory.mktemp("benchmark") / "adaptive"
    suite = load_suite("adaptive")
    suite.scenarios = suite.scenarios[:1]
    jobs = plan_jobs(["zoo:keep-lane"], suite, 1, out, references=False)
    run_jobs(jobs, workers=1, progress=False)
    (log,) = sorted((out / "logs").rglob("*.npz"))
    return log


@pytest.fixture(scope="session")
def benchmark_log_with_traffic(tmp_path_factory) -> Path:
    """One episode of adaptive a09 (a lead turning right at a signalised junction among built-in
    traffic) of zoo:keep-lane, written by the benchmark runner: its log carries the scene."""
    from smarts.benchmark.jobs import plan_jobs
    from smarts.benchmark.runner import run_jobs
    from smarts.benchmark.suites import load_suite

    out = tmp_path_factory.mktemp("benchmark") / "adaptive"
    jobs = plan_jobs(["zoo:keep-lane"], load_suite("adaptive"), 1, out, references=False)
    (job,) = [j for j in jobs if "a09_" in j.log_path]
    (result,) = run_jobs([job], workers=1, progress=False)
    return Path(result["log"])


@pytest.fixture(scope="session")
def finished(tmp_path_factory) -> Path:
    """A recording of the README's two agents driving through their intersection to their goals
    (both reach them: events to jump to)."""
    from smarts.env import DrivingParallelEnv
    from smarts.viz.watch import WatchedEnv

    env = WatchedEnv(DrivingParallelEnv("intersection_4way_signal_right"), record=tmp_path_factory.mktemp("finished"))
    drive(env)
    env.close()
    (path,) = env.recordings
    return Path(path)
