"""Run agents through a benchmark suite and write logs, scores and the report.

Each (agent, scenario, episode) is one job: build the scenario's env, reset it with the episode's
seed, drive every mission vehicle with the agent's batched policy, record the episode log and
write it to disk at once (so nothing is lost if a later job fails). Jobs run in worker processes
(libsumo allows one SUMO per process) or, with a Ray address, as Ray tasks on a cluster (each
worker needs this package installed and the output folder on a shared file system), results are scored by ``smarts.benchmark.metrics`` from
the written logs only. An agent that raises or returns a malformed action fails its episode with
the reason recorded; the suite goes on.
"""

from __future__ import annotations

import concurrent.futures as cf
import multiprocessing
import re
import traceback
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from smarts.benchmark.suites import Suite, load_suite

REFERENCE_AGENTS = ("zoo:keep-lane", "zoo:random")


@dataclass(frozen=True)
class Job:
    agent: str
    suite_source: str
    scenario_index: int
    episode: int
    seed: int
    log_path: str


def agent_label(locator: str) -> str:
    """A file-system friendly name for an agent locator or checkpoint path."""
    return re.sub(r"[^A-Za-z0-9_.-]+", "_", Path(locator).stem if "/" in locator else locator).strip("_")


def load_policy(locator: str, seed: int = 0):
    """A batched policy from a zoo locator (``zoo:keep-lane``, ``zoo:random``) or a PPO
    checkpoint file (``*.pt``); a clear error otherwise."""
    from zoo import make_policy

    if locator.endswith(".pt") or Path(locator).is_file():
        from agents.ppo import load_policy_file

        return load_policy_file(locator)
    policy = make_policy(locator)
    if hasattr(policy, "seed"):
        policy.seed(seed)
    return policy


def run_episode(job: Job) -> dict:
    """Run one episode and write its log; returns a short summary (never raises for agent faults)."""
    from smarts.benchmark.metrics import write_episode
    from smarts.benchmark.recorder import EpisodeRecorder
    from smarts.env import DrivingParallelEnv

    suite = load_suite(job.suite_source)
    entry = suite.scenarios[job.scenario_index]
    env = DrivingParallelEnv(entry.spec)
    try:
        obs, _ = env.reset(seed=job.seed)
        recorder = EpisodeRecorder(
            env.sim,
            env.possible_agents,
            scenario=entry.name,
            task=suite.task,
            episode=job.episode,
            seed=job.seed,
            time_limit=entry.time_limit,
            follow=entry.follow,
        )
        recorder.record()
        env.add_step_listener(lambda sim: recorder.record())
        try:
            policy = load_policy(job.agent, job.seed)
        except Exception as err:  # an unknown or broken agent fails every episode, visibly
            recorder.fail(f"could not load agent {job.agent!r}: {err}")
            policy = None
        leads = set(entry.follow.values())
        while policy is not None and env.agents:
            try:
                batch = {k: np.stack([obs[a][k] for a in env.agents]) for k in obs[env.agents[0]]}
                actions = np.asarray(policy.act(batch))
                obs, *_ = env.step(dict(zip(env.agents, actions)))
            except Exception as err:
                recorder.fail(f"{type(err).__name__}: {err}")
                break
            if leads and not all(lead in env.sim.table.row_of for lead in leads):
                break  # the lead left the map: the following task is over
        log = recorder.finish()
    finally:
        env.close()
    Path(job.log_path).parent.mkdir(parents=True, exist_ok=True)
    write_episode(log, Path(job.log_path))
    return {"agent": job.agent, "scenario": entry.name, "episode": job.episode, "failure": log.failure, "log": job.log_path}


def plan_jobs(agents: list[str], suite: Suite, episodes: int, out_dir: Path, seed: int | None = None) -> list[Job]:
    base = suite.seed if seed is None else seed
    jobs = []
    for agent in agents:
        for i, scenario in enumerate(suite.scenarios):
            for episode in range(episodes):
                path = out_dir / "logs" / agent_label(agent) / scenario.name / f"episode_{episode:03d}.npz"
                jobs.append(Job(agent, suite.source, i, episode, base + episode, str(path)))
    return jobs


def run_jobs(jobs: list[Job], workers: int = 1, progress: bool = True, ray_address: str | None = None) -> list[dict]:
    """Run jobs in ``workers`` processes (inline when 1), or as Ray tasks when ``ray_address`` is
    given (``auto``, ``local`` or ``HOST:PORT``); results in job order either way."""
    from rich.progress import Progress

    results: list[dict | None] = [None] * len(jobs)
    with Progress(disable=not progress, transient=False) as bar:
        task = bar.add_task("episodes", total=len(jobs))
        if ray_address:
            from smarts.ray_session import ray_session

            with ray_session(ray_address, num_cpus=max(2, workers)) as ray:
                remote = ray.remote(run_episode_guarded)
                pending = {remote.remote(job): k for k, job in enumerate(jobs)}
                while pending:
                    done, _ = ray.wait(list(pending), num_returns=1)
                    for ref in done:
                        results[pending.pop(ref)] = ray.get(ref)
                        bar.advance(task)
        elif workers <= 1:
            for k, job in enumerate(jobs):
                results[k] = run_episode_guarded(job)
                bar.advance(task)
        else:
            ctx = multiprocessing.get_context("spawn")
            with cf.ProcessPoolExecutor(max_workers=workers, mp_context=ctx) as pool:
                futures = {pool.submit(run_episode_guarded, job): k for k, job in enumerate(jobs)}
                for future in cf.as_completed(futures):
                    results[futures[future]] = future.result()
                    bar.advance(task)
    return results  # type: ignore[return-value]


def run_episode_guarded(job: Job) -> dict:
    """``run_episode`` that turns a crash of the episode itself into a recorded failure."""
    try:
        return run_episode(job)
    except Exception as err:
        return {"agent": job.agent, "episode": job.episode, "failure": f"{type(err).__name__}: {err}",
                "log": None, "traceback": traceback.format_exc()}  # fmt: skip
