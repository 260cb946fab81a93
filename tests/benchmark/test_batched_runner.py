"""The benchmark's batched path (``smarts.benchmark.batched``): a suite's episodes stepped as a few
simulations give the logs and results of one env per episode, bit for bit, and a batch whose
policy fails, whose worker dies or that runs out of time loses nothing."""

import dataclasses
import json
import time
from pathlib import Path

import numpy as np
import pytest

from smarts.benchmark.jobs import plan_jobs, plan_units
from smarts.benchmark.metrics import read_episode
from smarts.benchmark.report import write_report
from smarts.benchmark.runner import run_jobs
from smarts.benchmark.suites import load_suite
from tests.benchmark.batched_agents import resolve
from tests.benchmark.dying_agent import MARKER_DIR

HERE = Path(__file__).parent
TINY = str(HERE / "tiny_suite.yaml")
FOLLOW = str(HERE / "follow_suite.yaml")
SIGKILLED = "worker process died (exit code -9, killed by SIGKILL)"


@pytest.fixture
def marker_dir(tmp_path, monkeypatch):
    folder = tmp_path / "markers"
    folder.mkdir()
    monkeypatch.setenv(MARKER_DIR, str(folder))  # spawned workers (and Ray's) inherit it
    return folder


def _same(a, b, where: str) -> None:
    """``a`` and ``b`` equal bit for bit (arrays by value, dtype and NaN places), recursively."""
    if dataclasses.is_dataclass(a):
        for f in dataclasses.fields(a):
            if f.name != "source":  # the log's own path
                _same(getattr(a, f.name), getattr(b, f.name), f"{where}.{f.name}")
    elif isinstance(a, dict):
        assert a.keys() == b.keys(), where
        for k in a:
            _same(a[k], b[k], f"{where}[{k!r}]")
    elif isinstance(a, (list, tuple)):
        assert len(a) == len(b), where
        for i, (x, y) in enumerate(zip(a, b)):
            _same(x, y, f"{where}[{i}]")
    elif isinstance(a, np.ndarray):
        assert a.dtype == b.dtype and a.shape == b.shape, where
        np.testing.assert_array_equal(a, b, err_msg=where)
    elif isinstance(a, float) and np.isnan(a):
        assert isinstance(b, float) and np.isnan(b), where
    else:
        assert a == b, where


def _run_both(tmp_path, suite_file, agents, episodes, resolver=None, workers=1, references=None):
    """Per-episode and batched runs of the same jobs: (results, folder) of each; with the
    reference agents unless ``references`` is False (default: with the installed resolver)."""
    suite = load_suite(suite_file)
    references = resolver is None if references is None else references
    out = {}
    for batch in (False, True):
        folder = tmp_path / ("batched" if batch else "per_episode")
        jobs = plan_jobs(agents, suite, episodes, folder, policy_resolver=resolver, references=references)
        results = run_jobs(jobs, workers=workers, progress=False, policy_resolver=resolver, batch=batch)
        write_report(folder, suite, agents, results)
        out[batch] = (results, folder)
    return out


def _assert_identical(out) -> None:
    (singles, one), (batched, many) = out[False], out[True]
    assert len(singles) == len(batched)
    for a, b in zip(singles, batched):
        where = f"{a['agent']} {a['scenario']} #{a['episode']}"
        assert {k: v for k, v in a.items() if k != "log"} == {k: v for k, v in b.items() if k != "log"}, where
        if a["log"] is not None:
            _same(read_episode(a["log"]), read_episode(b["log"]), where)
    doc = [json.loads((folder / "results.json").read_text().replace(str(folder), "<run>")) for folder in (one, many)]
    assert doc[0] == doc[1]


@pytest.mark.parametrize("suite_file", [TINY, FOLLOW], ids=["collaborative", "following"])
def test_a_suite_gives_the_same_logs_and_results_batched_as_one_env_per_episode(tmp_path, suite_file):
    """Every kind of policy batching (``rows``: keep-lane and stand-still; ``instances``: random;
    ``episodes`` with ``act_episodes``: a PPO checkpoint), agents that crash early (the episode
    runs on for the lead), a lead leaving the map (the episode ends); the three reference agents
    (who drive alike) in one simulation, each episode acted in by its own agent's policy."""
    agents = ["zoo:platoon-rtp"]
    suite = load_suite(suite_file)
    jobs = plan_jobs(agents, suite, 2, tmp_path / "plan")
    units = plan_units(jobs, list(range(len(jobs))))
    n = 2 * len(suite.scenarios)
    assert sorted(map(len, units)) == [n, 3 * n]  # PPO's own simulation; the references' together
    assert {jobs[k].agent for k in max(units, key=len)} == {"zoo:keep-lane", "zoo:random", "zoo:stand-still"}
    out = _run_both(tmp_path, suite_file, agents, 2)
    _assert_identical(out)
    results = out[True][0]
    assert {r["agent"] for r in results} == {"zoo:platoon-rtp", "zoo:keep-lane", "zoo:random", "zoo:stand-still"}
    if suite_file == FOLLOW:  # both endings of a following episode happened
        ends = {r["scenario"]: read_episode(r["log"]).end_time for r in results if r["agent"] == "zoo:stand-still"}
        assert ends["f1_lead_stays"] == pytest.approx(6.0) and ends["f2_lead_leaves_the_map"] < 7.0


def test_the_ported_planners_give_the_same_logs_batched_as_one_env_per_episode(tmp_path):
    """TF, VCR and AID keep memory per agent across calls (``instances``: an instance per
    episode), with their learned parts (the stop/move veto, the event classifier over rasters,
    the motion predictor); a suite's episodes of each share one simulation."""
    agents = ["zoo:tf", "zoo:vcr", "zoo:aid"]
    suite = load_suite(TINY)
    jobs = plan_jobs(agents, suite, 1, tmp_path / "plan", references=False)
    assert sorted(map(len, plan_units(jobs, list(range(len(jobs)))))) == [len(suite.scenarios)] * 3
    _assert_identical(_run_both(tmp_path, TINY, agents, 1, references=False))


def test_sb3_and_v2v_checkpoints_give_the_same_logs_batched_as_one_env_per_episode(tmp_path):
    """A Stable-Baselines3 checkpoint (``episodes`` batching) and a PPO checkpoint trained with
    every sensor and V2V messaging (seeded losses, connected traffic): each episode's messages,
    sensors and actions are its own in a batch, so the logs equal one env per episode."""
    from train.__main__ import main

    common = ["--task", "platoon", "--total-steps", "64", "--envs", "2", "--frames-per-batch", "64",
              "--minibatch-size", "32", "--epochs", "1", "--eval-episodes", "0", "--quiet",
              "--scenarios", "adaptive:a01_straight_free"]  # fmt: skip
    sensors = ("{neighbours: {extended: true}, occlusion: {enabled: true, mode: hide}, lidar: {rays: 8, range: 30}, "
               "rasters: {size: 8, resolution: 2.0, layers: [drivable, occupancy, occlusion], rgb: true}}")  # fmt: skip
    v2v = "{range: 60, latency: 1, loss: 0.2, message_size: 4, max_messages: 4, penetration: 0.5}"
    assert main(["ppo", *common, "--lib", "sb3", "--out-dir", str(tmp_path / "sb3")]) == 0
    assert main(["ppo", *common, "--interface", sensors, "--comms", v2v, "--out-dir", str(tmp_path / "v2v")]) == 0
    agents = [str(tmp_path / "sb3" / "final.pt"), str(tmp_path / "v2v" / "final.pt")]
    suite = load_suite(FOLLOW)
    jobs = plan_jobs(agents, suite, 2, tmp_path / "plan", references=False)
    assert sorted(map(len, plan_units(jobs, list(range(len(jobs)))))) == [2 * len(suite.scenarios)] * 2
    out = _run_both(tmp_path, FOLLOW, agents, 2, references=False)
    _assert_identical(out)
    v2v_logs = [read_episode(r["log"]) for r in out[True][0] if r["agent"] == agents[1]]
    assert all(log.info["comms"]["loss"] == 0.2 for log in v2v_logs)


def test_episodes_whose_policy_fails_in_a_batch_are_recorded_as_alone(tmp_path):
    """A policy that raises in some episodes and sends NaN in others, each after a while: those
    episodes leave the batch and run alone, failing exactly as they always did, while the others
    go on batched."""
    out = _run_both(tmp_path, TINY, ["test:flaky"], 2, resolver=resolve)
    _assert_identical(out)
    failures = [(r["scenario"], r["failure"].split(":")[0]) for r in out[True][0]]
    assert failures == [("t1_left", "ActionError")] * 2 + [("t2_straight_traffic", "RuntimeError")] * 2
    assert all(read_episode(r["log"]).agents["agent_0"].time.size > 10 for r in out[True][0])


def test_plan_units_batches_what_can_share_a_simulation(tmp_path):
    suite_file = tmp_path / "suite.yaml"
    text = (
        Path(TINY)
        .read_text()
        .replace("traffic: {engine: builtin, density: low}", "traffic: {engine: sumo, density: low}")
    )
    suite_file.write_text(text)
    suite = load_suite(suite_file)
    jobs = plan_jobs(["zoo:keep-lane", "test:hang"], suite, 3, tmp_path / "run", references=False,
                     policy_resolver=_with_unbatched)  # fmt: skip
    units = plan_units(jobs, list(range(len(jobs))), policy_resolver=_with_unbatched)
    keep = [u for u in units if jobs[u[0]].agent == "zoo:keep-lane"]
    # t1_left's 3 episodes share a simulation; SUMO traffic (t2) runs one episode per process.
    assert sorted(map(len, keep)) == [1, 1, 1, 3]
    assert all(suite.scenarios[jobs[u[0]].scenario_index].name == "t2_straight_traffic" for u in keep if len(u) == 1)
    assert all(len(u) == 1 for u in units if jobs[u[0]].agent == "test:hang")  # no batching declared
    assert sorted(map(len, plan_units(jobs[:3], [0, 1, 2], workers=2))) == [1, 2]  # a unit per worker
    assert sorted(k for u in units for k in u) == list(range(len(jobs)))


def _with_unbatched(locator: str, /, **kwargs):
    from tests.benchmark.dying_agent import resolve as dying

    return dying(locator, **kwargs)


def test_a_batch_whose_worker_dies_runs_its_unfinished_episodes_again_alone(tmp_path, marker_dir):
    suite = load_suite(TINY)
    jobs = plan_jobs(["test:die-once-rows"], suite, 2, tmp_path, references=False, policy_resolver=resolve)
    assert [len(u) for u in plan_units(jobs, [0, 1, 2, 3], policy_resolver=resolve)] == [4]
    results = run_jobs(jobs, workers=1, episode_timeout=300.0, progress=False, policy_resolver=resolve)
    assert (marker_dir / "died").exists()  # the batch's worker really was killed
    assert all(r["failure"] is None for r in results) and all(read_episode(r["log"]).agents for r in results)
    assert [r.get("retried") for r in results] == [[SIGKILLED]] * 4  # each lost its worker once


def test_a_batch_past_the_episode_timeout_runs_its_unfinished_episodes_again_alone(tmp_path):
    """``test:hang-stacked`` hangs only in a call of several episodes' rows: the batch times out,
    its episodes run alone (each under the same limit) and finish; nothing is lost."""
    suite = load_suite(TINY)
    jobs = plan_jobs(["test:hang-stacked"], suite, 2, tmp_path, references=False, policy_resolver=resolve)
    start = time.monotonic()
    results = run_jobs(jobs, workers=1, episode_timeout=15.0, progress=False, policy_resolver=resolve)
    assert time.monotonic() - start < 140.0  # not stuck in the hung batch
    assert all(r["failure"] is None for r in results) and all(read_episode(r["log"]).agents for r in results)


def test_on_ray_batches_run_as_tasks_and_a_failed_one_loses_nothing(tmp_path, marker_dir):
    import ray  # noqa: F401  (installed by the test extra; never skipped)

    suite = load_suite(TINY)
    jobs = plan_jobs(["zoo:keep-lane", "test:die-once-rows"], suite, 1, tmp_path, references=False,
                     policy_resolver=resolve)  # fmt: skip
    results = run_jobs(jobs, progress=False, ray_address="local", policy_resolver=resolve)
    assert (marker_dir / "died").exists()
    assert all(r["failure"] is None for r in results) and all(read_episode(r["log"]).agents for r in results)
    died = [r for r in results if r["agent"] == "test:die-once-rows"]
    assert all(r["retried"][0].startswith("Ray task failed (") for r in died)
    inline = run_jobs(plan_jobs(["zoo:keep-lane"], suite, 1, tmp_path / "inline", references=False), progress=False)
    for a, b in zip(inline, results[: len(inline)]):
        _same(read_episode(a["log"]), read_episode(b["log"]), a["scenario"])
