"""Run agents through a benchmark suite and write their episode logs: :func:`run_jobs` and the
episode loop.

Each job (:mod:`smarts.benchmark.jobs`) resolves the agent's batched policy
(:mod:`smarts.benchmark.agents`), builds the scenario with every learning (non-social) agent in
the policy's own action space and controller (and the policy's observation interface when it
declares one), resets it with the episode's seed, drives every mission vehicle with the policy,
records the episode log and writes it to disk at once (so nothing is lost if a later job fails).
Episodes that can share a simulation run as one (:mod:`smarts.benchmark.batched`). Units run
inline, in worker processes or as Ray tasks (:mod:`smarts.benchmark.pool`). Results are scored by
``smarts.benchmark.metrics`` from the written logs only. An agent that raises or returns a
malformed action fails its episode with the reason recorded; the suite goes on.

Logs are written atomically (a temporary file, then ``os.replace``), so a killed run never leaves
a partial log. ``run_jobs(..., resume=True)`` skips the episodes whose logs are already there and
read back valid for the same job; Ctrl-C raises :class:`BenchmarkInterrupted` carrying the
episodes that finished.
"""

from __future__ import annotations

import contextlib
import os
import sys
import traceback
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import numpy as np

from smarts.benchmark.agents import PolicySetup, check_hosted, load_policy, policy_setup, scenario_for
from smarts.benchmark.jobs import (
    Job,
    episode_summary,
    finished_episode,
    job_inputs,
    plan_units,
    remove_partial_writes,
    write_failed_episode,
)
from smarts.benchmark.pool import run_in_processes, run_on_ray
from smarts.benchmark.suites import Suite, SuiteScenario, load_suite
from smarts.core.policies import PolicyResolver


class BenchmarkInterrupted(KeyboardInterrupt):
    """Ctrl-C during :func:`run_jobs`. ``results`` is in job order with None for every episode
    that did not finish; ``finished`` lists the others (their logs are on disk, so a run with
    ``resume=True`` does only the rest). A ``KeyboardInterrupt``, so code that does not look for
    it stops as before."""

    def __init__(self, results: list[dict | None]):
        super().__init__(f"interrupted: {sum(r is not None for r in results)} of {len(results)} episodes finished")
        self.results = results

    @property
    def finished(self) -> list[dict]:
        return [r for r in self.results if r is not None]

    @property
    def not_run(self) -> int:
        return sum(r is None for r in self.results)


def build_env(entry: SuiteScenario, setup: PolicySetup):
    """The env of a suite scenario for a policy: its action space, controller and interface."""
    from smarts.env import DrivingParallelEnv

    spec = scenario_for(entry.spec, setup)
    return DrivingParallelEnv(spec, observation=setup.interface, lane_relative=setup.lane_relative)


def _episode_info(job: Job, suite: Suite) -> dict[str, Any]:
    """The start of an episode log's ``info`` (the policy's setup follows). The suite travels with
    the log, so a viewer finds the scenario's map wherever the log is."""
    return {"agent": job.agent, "inputs": job_inputs(job), "suite": suite.name, "suite_source": suite.source}


def run_episode(job: Job, policy_resolver: PolicyResolver | None = None) -> dict:
    """Run one episode and write its log; returns a short summary (never raises for agent faults)."""
    from smarts.benchmark.metrics import write_episode
    from smarts.benchmark.recorder import EpisodeRecorder

    suite = load_suite(job.suite_source)
    entry = suite.scenarios[job.scenario_index]
    info = _episode_info(job, suite)
    try:
        policy = load_policy(job.agent, job.seed, policy_resolver)
        setup = policy_setup(policy, job.agent)
        check_hosted(job.agent, setup, suite)
    except Exception as err:  # an unknown, broken or misdeclared agent fails every episode, visibly
        return write_failed_episode(job, f"could not load agent {job.agent!r}: {err}")
    info.update(setup.to_dict())
    env = build_env(entry, setup)
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
            info=info,
        )
        env.add_step_listener(lambda sim: recorder.record())
        running = True
        if hasattr(policy, "check_space") and env.possible_agents:
            try:  # a checkpoint that reads other observation keys or shapes fails here, plainly
                policy.check_space(env.observation_space(env.possible_agents[0]))
            except Exception as err:
                recorder.fail(f"{type(err).__name__}: {err}")
                running = False
        leads = set(entry.follow.values())
        while running and env.agents and env.sim.time < entry.time_limit - 1e-9:
            try:
                batch = {k: np.stack([obs[a][k] for a in env.agents]) for k in obs[env.agents[0]]}
                actions = np.asarray(policy.act(batch))
                obs, *_ = env.step(dict(zip(env.agents, actions)))
            except Exception as err:
                recorder.fail(f"{type(err).__name__}: {err}")
                break
            if leads and not all(lead in env.sim.table.row_of for lead in leads):
                break  # the lead left the map: the following task is over
        # Followers that crashed or left the road did not complete the scenario: it runs on to its
        # end (the time limit or the lead leaving the map), so their goal is where the lead gets
        # to and SFD counts the steps they missed.
        while (running and recorder.failure is None and leads and not env.agents
               and env.sim.time < entry.time_limit - 1e-9
               and all(lead in env.sim.table.row_of for lead in leads)):  # fmt: skip
            env.step({})
        log = recorder.finish()
    finally:
        env.close()
    Path(job.log_path).parent.mkdir(parents=True, exist_ok=True)
    write_episode(log, Path(job.log_path))
    return episode_summary(job, entry.name, log.failure, info)


def run_jobs(
    jobs: list[Job],
    workers: int = 1,
    progress: bool = True,
    ray_address: str | None = None,
    policy_resolver: PolicyResolver | None = None,
    *,
    resume: bool = False,
    episode_timeout: float | None = None,
    batch: bool = True,
    on_result: Callable[[dict], None] | None = None,
) -> list[dict]:
    """Run jobs in ``workers`` processes (inline when 1), or as Ray tasks when ``ray_address`` is
    given (``auto``, ``local`` or ``HOST:PORT``); results in job order either way.

    ``batch``: the episodes of an agent whose policy declares how it may be shared
    (``policy.batching``, :mod:`smarts.benchmark.batched`) run as a few simulations of many
    episodes each (:func:`plan_units`: a unit is one job for a worker or a Ray task), with the
    same logs, bit for bit, as one env per episode; episodes that cannot share a simulation (SUMO
    traffic) and agents without that declaration run one episode per unit. False: every episode
    alone, as the per-episode runner always did.
    ``policy_resolver`` (None: the installed default) goes to every worker, so it must pickle:
    a module-level function or an instance of a module-level class.

    A worker process that dies costs only its episode: it runs again in a fresh worker
    (:data:`smarts.benchmark.pool.RETRIES` times), then is recorded as failed with how the process ended (its summary
    has ``attempts``; one that succeeded on a later attempt has ``retried``, the reasons).
    ``resume``: an episode whose log is already at its path, reads back valid and is of this job
    (same agent, scenario, episode, seed and :func:`job_inputs`) is not run again; logs of
    episodes lost to dead workers are. Ctrl-C stops the workers and raises
    :class:`BenchmarkInterrupted` with the episodes that finished.

    ``episode_timeout`` (seconds, None: no limit): a worker still on one episode after that long
    is killed and the episode recorded as failed, once (a hang would only repeat); the other
    episodes go on. A unit of several episodes (which all start together) past that long has its
    unfinished episodes run again, each alone under the same limit. With it, even ``workers`` 1
    runs in a worker process. Not for Ray tasks. A unit whose worker dies likewise keeps the
    episodes it finished and runs the others again, each alone.

    ``on_result(summary)`` is called as each episode's result is known (a reused log's too), in
    this process (``smarts.benchmark.report.ReportAhead.offer`` prepares the report meanwhile)."""
    if episode_timeout is not None and not episode_timeout > 0:
        raise ValueError(f"episode_timeout: expected a positive number of seconds, got {episode_timeout!r}")
    if episode_timeout is not None and ray_address:
        raise ValueError("episode_timeout: not supported for Ray tasks; run without ray_address")
    from rich.progress import Progress

    results: list[dict | None] = [None] * len(jobs)
    with Progress(disable=not progress, transient=False) as bar:
        task = bar.add_task("episodes", total=len(jobs))

        def done(k: int, result: dict) -> None:
            results[k] = result
            bar.advance(task)
            if on_result is not None:
                on_result(result)

        todo = []
        for k, job in enumerate(jobs):
            if resume and not job.reuse:  # (a shared reference cache may be being written by another run)
                remove_partial_writes(job)
            kept = finished_episode(job) if resume or job.reuse else None
            if kept is not None:
                done(k, kept)
            else:
                todo.append(k)
        try:
            units = plan_units(jobs, todo, workers, policy_resolver) if batch else [[k] for k in todo]
            if not units:
                pass
            elif ray_address:
                run_on_ray(jobs, units, ray_address, workers, policy_resolver, done, run_unit_collected)
            elif workers <= 1 and episode_timeout is None:
                for unit in units:
                    run_unit([jobs[k] for k in unit], policy_resolver, lambda i, r, unit=unit: done(unit[i], r))
            else:
                run_in_processes(jobs, units, max(workers, 1), policy_resolver, done, run_unit, episode_timeout)
        except KeyboardInterrupt:
            raise BenchmarkInterrupted(results) from None
    return results  # type: ignore[return-value]


def run_unit_collected(jobs: list[Job], policy_resolver: PolicyResolver | None = None) -> list[dict]:
    """:func:`run_unit`'s summaries in job order (a Ray task's result)."""
    results: list[dict | None] = [None] * len(jobs)

    def report(i: int, result: dict) -> None:
        results[i] = result

    run_unit(jobs, policy_resolver, report)
    return results  # type: ignore[return-value]


def run_episode_guarded(job: Job, policy_resolver: PolicyResolver | None = None) -> dict:
    """``run_episode`` that turns a crash of the episode itself into a recorded failure (and
    reuses a cached log for a job marked ``reuse``)."""
    if job.reuse:
        kept = finished_episode(job)
        if kept is not None:
            return kept
    try:
        return run_episode(job, policy_resolver)
    except Exception as err:
        scenario = None
        try:
            scenario = load_suite(job.suite_source).scenarios[job.scenario_index].name
        except Exception:
            pass
        return {"agent": job.agent, "scenario": scenario, "episode": job.episode, "seed": job.seed,
                "failure": f"{type(err).__name__}: {err}", "log": None, "traceback": traceback.format_exc()}  # fmt: skip


def run_unit(jobs: list[Job], policy_resolver: PolicyResolver | None, report: Callable[[int, dict], None]) -> None:
    """Run a unit of jobs (:func:`plan_units`), calling ``report(i, summary)`` as ``jobs[i]``
    finishes (its log is on disk by then): one job alone, several as one simulation, where those
    that leave the batch run alone after it."""
    with _one_torch_thread():
        if len(jobs) == 1:
            report(0, run_episode_guarded(jobs[0], policy_resolver))
            return
        _run_several(jobs, policy_resolver, report)


@contextlib.contextmanager
def _one_torch_thread() -> Iterator[None]:
    """Policies' networks on one thread while episodes run: their batches are a few rows, where
    more threads only wait for each other (on a busy machine a call took 30 times as long), and
    the benchmark's parallelism is its worker processes. (The results are the same: measured
    bit for bit on the whole adaptive suite.) Where torch is not imported yet (a worker whose
    policies need none: 2 s saved), it is not imported for this: a policy that imports it
    meanwhile starts with one thread (``OMP_NUM_THREADS``, read once as torch loads)."""
    torch = sys.modules.get("torch")
    if torch is None:
        before_env = os.environ.get("OMP_NUM_THREADS")
        os.environ["OMP_NUM_THREADS"] = "1"
        try:
            yield
        finally:
            if before_env is None:
                os.environ.pop("OMP_NUM_THREADS", None)
            else:
                os.environ["OMP_NUM_THREADS"] = before_env
        return
    before = torch.get_num_threads()
    torch.set_num_threads(1)
    try:
        yield
    finally:
        torch.set_num_threads(before)


def _run_several(jobs: list[Job], policy_resolver: PolicyResolver | None, report: Callable[[int, dict], None]) -> None:
    """:func:`run_unit` of several jobs: reused logs, then one simulation (per step length) of
    the rest, then alone whatever left it (or all that did not finish, should the batch itself
    fail)."""
    todo, reported = [], set()

    def mark(i: int, result: dict) -> None:
        reported.add(i)
        report(i, result)

    for i, job in enumerate(jobs):
        kept = finished_episode(job) if job.reuse else None
        if kept is not None:
            mark(i, kept)
        else:
            todo.append(i)
    try:
        alone = _run_batched(jobs, todo, policy_resolver, mark) if todo else []
    except Exception:  # noqa: BLE001 - alone, each episode records what happens to it
        alone = [i for i in todo if i not in reported]
    for i in alone:
        mark(i, run_episode_guarded(jobs[i], policy_resolver))


def _run_batched(jobs: list[Job], todo: list[int], policy_resolver: PolicyResolver | None,
                 report: Callable[[int, dict], None]) -> list[int]:  # fmt: skip
    """Run ``jobs[todo]`` in simulations of many episodes, one per step length and way of
    driving (the agents whose policies have the same action space, controller and observation
    interface share one, each episode acted in by its own agent's policy); returns those that
    must run alone."""
    from smarts.benchmark.batched import BatchEpisode, run_batch
    from smarts.benchmark.batching import batching_mode, solo_reason

    agents: dict[tuple[str, str], tuple | None] = {}  # (agent, suite) -> suite, policy, setup, batching
    alone, groups = [], {}
    for i in todo:
        job = jobs[i]
        key = (job.agent, job.suite_source)
        if key not in agents:
            agents[key] = None
            try:
                suite = load_suite(job.suite_source)
                policy = load_policy(job.agent, job.seed, policy_resolver)
                setup = policy_setup(policy, job.agent)
                check_hosted(job.agent, setup, suite)
                agents[key] = (suite, policy, setup, batching_mode(policy))
            except Exception:  # noqa: BLE001 - alone, each episode records why
                pass
        if agents[key] is None or agents[key][3] is None:
            alone.append(i)
            continue
        suite, policy, setup, mode = agents[key]
        entry = suite.scenarios[job.scenario_index]
        spec = scenario_for(entry.spec, setup)
        if solo_reason(spec, setup.interface) is not None:
            alone.append(i)
            continue
        try:
            own = load_policy(job.agent, job.seed, policy_resolver) if mode == "instances" else policy
        except Exception:  # noqa: BLE001
            alone.append(i)
            continue
        meta = dict(scenario=entry.name, task=suite.task, episode=job.episode, seed=job.seed,
                    time_limit=entry.time_limit, follow=entry.follow, info={**_episode_info(job, suite), **setup.to_dict()})  # fmt: skip
        group = groups.setdefault((spec.step_length, repr(setup)), (setup, []))
        group[1].append((i, BatchEpisode(spec, job.seed, meta, own, mode)))
    for setup, members in groups.values():
        index = [i for i, _ in members]

        def finished(b: int, log, index=index) -> None:
            report(index[b], _write_batched(jobs[index[b]], log))

        alone += [index[b] for b in run_batch([e for _, e in members], setup.interface, setup.lane_relative,
                                              finished)]  # fmt: skip
    return sorted(alone)


def _write_batched(job: Job, log) -> dict:
    """Write a batched episode's log (as :func:`run_episode` writes its own) and return its summary."""
    from smarts.benchmark.metrics import write_episode

    try:
        Path(job.log_path).parent.mkdir(parents=True, exist_ok=True)
        write_episode(log, Path(job.log_path))
    except Exception as err:  # noqa: BLE001 - as run_episode_guarded reports a crash
        return {"agent": job.agent, "scenario": log.scenario, "episode": job.episode, "seed": job.seed,
                "failure": f"{type(err).__name__}: {err}", "log": None, "traceback": traceback.format_exc()}  # fmt: skip
    return episode_summary(job, log.scenario, log.failure, log.info)
