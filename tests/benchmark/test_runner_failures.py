"""Runs users can rely on: a dead worker process costs one episode at most, an interrupted run
reports what finished and ``--resume`` finishes it without redoing work."""

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from smarts.benchmark.jobs import finished_episode, plan_jobs, write_failed_episode
from smarts.benchmark.metrics import MetricParams, read_episode
from smarts.benchmark.report import write_report
from smarts.benchmark.runner import run_jobs
from smarts.benchmark.suites import load_suite
from tests.benchmark.dying_agent import MARKER_DIR, resolve
from train.__main__ import main

ROOT = Path(__file__).resolve().parents[2]
TINY = str(Path(__file__).with_name("tiny_suite.yaml"))
SIGKILLED = "worker process died (exit code -9, killed by SIGKILL)"


@pytest.fixture
def marker_dir(tmp_path, monkeypatch):
    folder = tmp_path / "markers"
    folder.mkdir()
    monkeypatch.setenv(MARKER_DIR, str(folder))  # spawned workers (and Ray's) inherit it
    return folder


def _by_agent(results, agent):
    return [r for r in results if r["agent"] == agent]


def test_a_worker_that_dies_is_replaced_and_its_episode_runs_again(tmp_path, marker_dir):
    suite = load_suite(TINY)
    jobs = plan_jobs(["test:die-once"], suite, 1, tmp_path, policy_resolver=resolve)
    results = run_jobs(jobs, workers=2, progress=False, policy_resolver=resolve)
    assert (marker_dir / "died").exists()  # a worker really was killed
    assert len(results) == 4 * 2 and all(r["failure"] is None for r in results)
    retried = [r for r in results if r.get("retried")]
    assert len(retried) == 1 and retried[0]["agent"] == "test:die-once"
    assert retried[0]["retried"] == [SIGKILLED]
    assert all(read_episode(r["log"]).agents for r in results)  # every episode has its full log
    write_report(tmp_path, suite, ["test:die-once"], results)
    doc = json.loads((tmp_path / "results.json").read_text())
    assert doc["complete"] and doc["failures"] == []
    assert doc["retried"] == [
        {k: retried[0][k] for k in ("agent", "scenario", "episode", "seed")} | {"reasons": [SIGKILLED]}
    ]
    assert "## Episodes run again after their worker process died" in (tmp_path / "report.md").read_text()


def test_an_episode_whose_worker_always_dies_fails_with_the_reason_and_the_rest_goes_on(tmp_path, marker_dir):
    suite = load_suite(TINY)
    jobs = plan_jobs(
        ["test:die-always", "zoo:keep-lane"], suite, 1, tmp_path, references=False, policy_resolver=resolve
    )
    results = run_jobs(jobs, workers=2, progress=False, policy_resolver=resolve)
    dead = _by_agent(results, "test:die-always")
    reason = f"{SIGKILLED} on all 2 attempts, each in its own worker"
    assert [(r["failure"], r["attempts"]) for r in dead] == [(reason, 2)] * 2
    log = read_episode(dead[0]["log"])  # a failed log, scored like any failed episode
    assert log.failure == reason and log.info["worker_died"]
    keep = _by_agent(results, "zoo:keep-lane")
    assert [r["failure"] for r in keep] == [None, None] and all(read_episode(r["log"]).agents for r in keep)
    write_report(tmp_path, suite, ["test:die-always", "zoo:keep-lane"], results)
    doc = json.loads((tmp_path / "results.json").read_text())
    assert [(f["agent"], f["scenario"], f["failure"]) for f in doc["failures"]] == [
        ("test:die-always", "t1_left", reason), ("test:die-always", "t2_straight_traffic", reason)]  # fmt: skip
    assert doc["agents"]["test:die-always"]["scores"]["overall"]["S_bench"] == 0.0
    assert doc["agents"]["zoo:keep-lane"]["scores"]["overall"]["S_bench"] > 0.3
    report = (tmp_path / "report.md").read_text()
    assert f"test:die-always: t1_left #0 (seed 7): {reason}" in report
    assert (
        f"**Every episode of test:die-always failed**, so its row scores failures, not driving. Reason: {reason}."
        in report
    )
    assert "Every episode of zoo:keep-lane" not in report
    # A resumed run gives episodes lost to dead workers another chance (and keeps the others).
    assert finished_episode(jobs[0]) is None and finished_episode(jobs[-1]) is not None


def test_an_episode_that_hangs_fails_after_the_timeout_and_the_rest_goes_on(tmp_path, marker_dir):
    suite = load_suite(TINY)
    jobs = plan_jobs(["test:hang", "zoo:keep-lane"], suite, 1, tmp_path, references=False, policy_resolver=resolve)
    start = time.monotonic()
    results = run_jobs(jobs, workers=2, progress=False, policy_resolver=resolve, episode_timeout=20.0)
    assert time.monotonic() - start < 120.0  # not stuck on the hung episodes
    hung = _by_agent(results, "test:hang")
    reason = "timed out: still running after 20 s (episode timeout)"
    assert [r["failure"] for r in hung] == [reason, reason]
    log = read_episode(hung[0]["log"])
    assert log.failure == reason and log.info["timed_out"] and log.info["worker_died"]
    keep = _by_agent(results, "zoo:keep-lane")
    assert [r["failure"] for r in keep] == [None, None] and all(read_episode(r["log"]).agents for r in keep)
    assert finished_episode(jobs[0]) is None  # a resumed run tries a timed-out episode again


def test_the_episode_timeout_is_checked(tmp_path):
    suite = load_suite(TINY)
    jobs = plan_jobs(["zoo:keep-lane"], suite, 1, tmp_path, references=False)
    with pytest.raises(ValueError, match="episode_timeout: expected a positive number of seconds, got 0"):
        run_jobs(jobs, progress=False, episode_timeout=0)
    with pytest.raises(SystemExit) as stop:
        main(["benchmark", "--suite", TINY, "--episode-timeout", "-1", "--out", str(tmp_path / "cli")])
    assert stop.value.code == 2 and not (tmp_path / "cli").exists()


def test_on_ray_a_task_whose_worker_dies_is_run_again_or_becomes_a_failed_episode(tmp_path, marker_dir):
    import ray  # noqa: F401  (installed by the test extra; never skipped)

    suite = load_suite(TINY)
    jobs = plan_jobs(
        ["test:die-once", "test:die-always"], suite, 1, tmp_path, references=False, policy_resolver=resolve
    )
    results = run_jobs(jobs, progress=False, ray_address="local", policy_resolver=resolve)
    assert (marker_dir / "died").exists()
    once, always = _by_agent(results, "test:die-once"), _by_agent(results, "test:die-always")
    assert [r["failure"] for r in once] == [None, None]  # Ray ran the killed task again
    assert all(r["failure"].startswith("Ray task failed (WorkerCrashedError: ") for r in always)
    assert all(read_episode(r["log"]).info["worker_died"] for r in always)
    write_report(tmp_path, suite, ["test:die-once", "test:die-always"], results)
    doc = json.loads((tmp_path / "results.json").read_text())
    assert [f["agent"] for f in doc["failures"]] == ["test:die-always"] * 2


def test_the_report_is_written_when_every_episode_failed_and_failed_episodes_are_excluded(tmp_path, monkeypatch):
    import smarts.benchmark.report as report

    suite = load_suite(TINY)
    jobs = plan_jobs(["zoo:stand-still"], suite, 1, tmp_path, references=False)
    results = [write_failed_episode(job, SIGKILLED, {"worker_died": True}) for job in jobs]
    monkeypatch.setattr(report, "load_params", lambda: MetricParams(failed_episodes="exclude"))
    write_report(tmp_path, suite, ["zoo:stand-still"], results)
    doc = json.loads((tmp_path / "results.json").read_text())
    assert doc["agents"]["zoo:stand-still"]["scores"] is None
    assert [(f["scenario"], f["failure"]) for f in doc["failures"]] == [
        ("t1_left", SIGKILLED),
        ("t2_straight_traffic", SIGKILLED),
    ]


def _bench(out, *extra):
    return main(["benchmark", "--suite", TINY, "--agent", "zoo:keep-lane", "--quiet", "--out", str(out), *extra])


def test_resume_runs_only_missing_or_broken_episodes(tmp_path, capsys):
    out = tmp_path / "run"
    assert _bench(out, "--episodes", "1", "--workers", "1") == 0
    first = json.loads((out / "results.json").read_text())
    logs = sorted((out / "logs").rglob("*.npz"))
    assert len(logs) == 3 * 2
    missing, cut, stale = logs[0], logs[3], logs[5]
    missing.unlink()
    cut.write_bytes(cut.read_bytes()[:500])  # a partial file (what a non-atomic writer could leave)
    leftover = stale.with_name(f".tmp-{stale.name}-123")  # a killed writer's temporary file (smarts.files)
    leftover.write_bytes(b"half")
    before = {p: p.stat().st_mtime_ns for p in logs if p not in (missing, cut)}
    assert _bench(out, "--episodes", "1", "--workers", "1", "--resume") == 0
    assert {p: p.stat().st_mtime_ns for p in before} == before  # valid logs are not redone
    assert missing.is_file() and read_episode(cut).agents  # the others are run again
    assert not leftover.exists()
    again = json.loads((out / "results.json").read_text())
    assert again["complete"] and _overall(again) == _overall(first)


def test_resume_runs_again_what_a_changed_suite_invalidates(tmp_path):
    suite_file = tmp_path / "suite.yaml"
    suite_file.write_text(Path(TINY).read_text())
    jobs = plan_jobs(["zoo:stand-still"], load_suite(suite_file), 1, tmp_path, references=False)
    run_jobs(jobs, progress=False)
    assert all(finished_episode(j) for j in jobs)
    suite_file.write_text(Path(TINY).read_text().replace("time_limit: 3", "time_limit: 2"))
    jobs = plan_jobs(["zoo:stand-still"], load_suite(suite_file), 1, tmp_path, references=False)
    assert not any(finished_episode(j) for j in jobs)
    results = run_jobs(jobs, progress=False, resume=True)
    assert read_episode(results[1]["log"]).time_limit == 2


def test_resume_runs_again_the_episodes_of_a_zoo_agent_whose_checkpoint_changed(tmp_path, monkeypatch):
    """A ``zoo:`` locator names the same agent after its checkpoint is updated: resume keys its
    episodes by the checkpoint's contents, so the old episodes are not reused."""
    import shutil

    import torch

    import zoo.registry

    checkpoint = tmp_path / "drive.pt"
    shutil.copy(Path(zoo.registry.ZOO_DIR) / "checkpoints" / "drive.pt", checkpoint)  # the shipped file stays as it is
    monkeypatch.setitem(zoo.registry.ZOO, "updated", (zoo.registry.CHECKPOINT, str(checkpoint), "a test entry"))
    suite = load_suite(TINY)
    jobs = plan_jobs(["zoo:updated"], suite, 1, tmp_path / "run", references=False)
    run_jobs(jobs, progress=False)
    assert all(finished_episode(j) for j in plan_jobs(["zoo:updated"], suite, 1, tmp_path / "run", references=False))
    before = {j.log_path: read_episode(j.log_path).info["inputs"] for j in jobs}
    blob = torch.load(checkpoint, weights_only=True)
    blob["actor"]["net.4.bias"] += 0.5  # retrained: other actions
    torch.save(blob, checkpoint)
    jobs = plan_jobs(["zoo:updated"], suite, 1, tmp_path / "run", references=False)
    assert not any(finished_episode(j) for j in jobs)
    run_jobs(jobs, progress=False, resume=True)
    assert all(finished_episode(j) for j in jobs)  # run again, for this checkpoint
    assert all(read_episode(j.log_path).info["inputs"] != before[j.log_path] for j in jobs)


def test_every_zoo_agent_with_learned_weights_is_keyed_by_its_checkpoint_file():
    import zoo.registry
    from smarts.benchmark.agents import policy_files_digest
    from zoo import make_policy

    learned = {"platoon-rtp", "drive", "platoon-c", "tf", "vcr", "aid"}
    for name in zoo.registry.ZOO:
        digest = policy_files_digest(make_policy(f"zoo:{name}"))
        assert bool(digest) == (name in learned), name


def _overall(doc):
    return {a: v["scores"]["overall"] for a, v in doc["agents"].items()}


def _as_from_a_terminal() -> None:
    """In the child: Ctrl-C acts as in a terminal even when the tests themselves were started in
    the background (a shell's background jobs ignore SIGINT, and children inherit that), and the
    benchmark runs below the test's priority so that on a loaded machine it cannot play all its
    episodes while the test waits for the CPU to look at the logs."""
    signal.signal(signal.SIGINT, signal.SIG_DFL)
    os.nice(10)


def test_ctrl_c_writes_what_finished_and_resume_finishes_the_run(tmp_path):
    out = tmp_path / "run"
    # One episode per unit, so episodes end one by one: in batches, the reference agents' episodes
    # (one simulation per worker) end almost together, and the run may be over by the Ctrl-C.
    command = [sys.executable, "-m", "train", "benchmark", "--suite", TINY, "--agent", "zoo:keep-lane",
               "--episodes", "12", "--workers", "2", "--per-episode", "--out", str(out)]  # fmt: skip
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    proc = subprocess.Popen(command, cwd=ROOT, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            start_new_session=True, preexec_fn=_as_from_a_terminal)  # fmt: skip
    try:
        deadline = time.monotonic() + 120
        while len(list((out / "logs").rglob("*.npz"))) < 4 and proc.poll() is None and time.monotonic() < deadline:
            time.sleep(0.02)
        os.killpg(proc.pid, signal.SIGINT)  # Ctrl-C in a terminal: the whole process group
        _, err = proc.communicate(timeout=60)
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
    assert proc.returncode == 130, err
    assert "Traceback" not in err
    lines = [line for line in err.splitlines() if line.strip()]
    assert len(lines) == 1 and lines[0].startswith("interrupted: ") and "--resume" in lines[0]
    doc = json.loads((out / "results.json").read_text())
    done = sorted((out / "logs").rglob("*.npz"))
    finished = 3 * 2 * 12 - doc["episodes_not_run"]
    # A worker may have written the logs of a batch's episodes that ended together before the parent
    # heard of them; --resume keeps every log on disk (their stamps, below) and runs only the rest.
    assert not doc["complete"] and 0 < finished <= len(done)
    assert "**Incomplete:**" in (out / "report.md").read_text()
    stamps = {p: p.stat().st_mtime_ns for p in done}
    assert _bench(out, "--episodes", "12", "--workers", "1", "--resume") == 0
    assert {p: p.stat().st_mtime_ns for p in done} == stamps
    doc = json.loads((out / "results.json").read_text())
    assert doc["complete"] and doc["episodes_not_run"] == 0
    assert sum(doc["agents"]["zoo:keep-lane"]["scores"]["episodes"].values()) == 2 * 12


def test_a_ctrl_c_while_a_worker_starts_is_not_lost():
    """Worker starts hold Ctrl-C back from the child (born with it blocked), but the parent still
    gets it: it is never ignored and lost."""
    from smarts.worker_processes import sigint_deferred

    probe = "import signal; print(signal.SIGINT in signal.pthread_sigmask(signal.SIG_BLOCK, []))"
    before = signal.signal(signal.SIGINT, signal.default_int_handler)  # as in a terminal, even in the background
    try:
        with pytest.raises(KeyboardInterrupt):
            with sigint_deferred():
                child = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True)
                os.kill(os.getpid(), signal.SIGINT)
                time.sleep(0.1)
    finally:
        signal.signal(signal.SIGINT, before)
    assert child.stdout.strip() == "True"
    assert signal.SIGINT not in signal.pthread_sigmask(signal.SIG_BLOCK, [])  # the parent's mask is restored


def test_workers_run_in_the_folder_and_environment_the_parent_has_when_they_start(tmp_path, monkeypatch):
    """Workers come from a fork server that may have started long before (``train benchmark``
    starts it first thing); they still see the parent's folder and environment of the moment they
    start, as fresh interpreters would."""
    from smarts.benchmark.pool import run_in_processes
    from smarts.worker_processes import start_worker_server
    from tests.benchmark.worker_probe import PROBE_VAR, where_and_what

    start_worker_server()
    monkeypatch.chdir(tmp_path)
    monkeypatch.setenv(PROBE_VAR, "set after the server started")
    seen = {}
    run_in_processes([None, None], [[0], [1]], 2, None, seen.__setitem__, where_and_what)
    assert sorted(seen) == [0, 1]
    assert {r["cwd"] for r in seen.values()} == {str(tmp_path)}
    assert {r["probe"] for r in seen.values()} == {"set after the server started"}
    assert len({r["pid"] for r in seen.values()} | {os.getpid()}) == 3
