"""Run units of benchmark jobs in worker processes, with retries and timeouts, or as Ray tasks.

Jobs run in worker processes (libsumo allows one SUMO per process) or, with a Ray address, as Ray
tasks on a cluster (each worker needs this package installed and the output folder on a shared
file system). A worker process that dies (killed, out of memory, a crash in native code) loses
only the episode it was running: that episode runs once more in a fresh worker (:data:`RETRIES`),
and if its worker dies again it is recorded as a failed episode whose reason says how the process
ended; the other episodes go on. On Ray, Ray runs a task whose worker died once more, and a task
that still fails becomes a failed episode the same way. Ctrl-C is the parent's alone: it stops
the workers (:func:`sigint_deferred`).

The function that runs a unit is given by the caller (a module-level function, so
workers and Ray tasks receive it by reference): this module never imports the runner, which
imports it.
"""

from __future__ import annotations

import contextlib
import multiprocessing
import multiprocessing.connection
import os
import signal
import time
from collections import deque
from collections.abc import Callable
from typing import Any

from smarts.benchmark.jobs import Job, finished_episode, write_failed_episode
from smarts.core.policies import PolicyResolver
from smarts.worker_processes import sigint_deferred, worker_context

RETRIES = 1
"""How many times an episode whose worker process died runs again, in a fresh worker, before it is
recorded as failed (on Ray: the task's ``max_retries``)."""


def _death(code: int | None) -> str:
    if code is None:
        return "worker process stopped answering"
    if code < 0:
        try:
            return f"worker process died (exit code {code}, killed by {signal.Signals(-code).name})"
        except ValueError:
            return f"worker process died (exit code {code}, killed by signal {-code})"
    return f"worker process died (exit code {code})"


def _lost(job: Job, reasons: list[str], info: dict[str, Any] | None = None) -> dict:
    """The failed episode of a job whose every attempt lost its worker (or ran out of time): a
    log saying why (so the report scores and lists it like any failed episode), or just the
    summary if even that fails. ``--resume`` runs such episodes again."""
    n = len(reasons)
    reason = reasons[-1] + ("" if n == 1 else f" on all {n} attempts, each in its own worker")
    try:
        summary = write_failed_episode(job, reason, {"worker_died": True, **(info or {})})
    except Exception as err:
        summary = {"agent": job.agent, "scenario": None, "episode": job.episode, "seed": job.seed,
                   "failure": reason, "log": None, "traceback": f"{type(err).__name__}: {err}"}  # fmt: skip
    return {**summary, "attempts": n}


RunUnit = Callable[[list[Job], "PolicyResolver | None", Callable[[int, dict], None]], None]
"""Runs a unit of jobs, calling ``report(i, summary)`` as ``jobs[i]`` finishes (the runner's
``run_unit``); a module-level function, so workers receive it by reference."""


def _worker_loop(conn, run_unit: RunUnit, policy_resolver: PolicyResolver | None, cwd: str,
                 environ: dict[str, str]) -> None:  # fmt: skip
    """A worker process: run the units it is sent with ``run_unit``, one at a time, until told to
    stop; each finished episode is sent at once (``("episode", k, summary)``, so a unit whose
    process dies loses only the episodes it had not finished), then ``("unit", None, None)``.
    It works in the parent's folder and environment as they were when it started (a fork server
    may have started before either changed)."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    if hasattr(signal, "pthread_sigmask"):
        signal.pthread_sigmask(signal.SIG_UNBLOCK, {signal.SIGINT})  # blocked by the parent for the start
    os.chdir(cwd)
    os.environ.clear()
    os.environ.update(environ)
    while True:
        try:
            message = conn.recv()
        except (EOFError, OSError):
            return  # the parent is gone
        if message is None:
            return
        ks, jobs = message
        run_unit(jobs, policy_resolver, lambda i, result: conn.send(("episode", ks[i], result)))
        conn.send(("unit", None, None))


class _Worker:
    """One worker process and the pipe to it; ``unit`` is the job indices it is running (None:
    idle) and ``pending`` those of them not reported yet."""

    def __init__(self, ctx, run_unit: RunUnit, policy_resolver: PolicyResolver | None):
        self.conn, child = ctx.Pipe()
        self.process = ctx.Process(
            target=_worker_loop,
            args=(child, run_unit, policy_resolver, os.getcwd(), dict(os.environ)),
            name="smarts-benchmark-worker",
        )
        with sigint_deferred():
            self.process.start()
        child.close()
        self.unit: list[int] | None = None
        self.pending: list[int] = []
        self.broken = False
        self.since = 0.0  # time.monotonic() when it was given its unit

    def give(self, unit: list[int], jobs: list[Job]) -> bool:
        try:
            self.conn.send((unit, [jobs[k] for k in unit]))
        except OSError:  # it died while idle
            return False
        self.unit, self.pending = unit, list(unit)
        self.since = time.monotonic()
        return True

    def drain(self) -> list[tuple[int, dict]]:
        """The finished episodes waiting in the pipe, as ``(k, summary)``; the unit is over
        (``unit`` None) once its end arrives; ``broken`` once the pipe is (the process died)."""
        out = []
        try:
            while self.unit is not None and self.conn.poll():
                kind, k, result = self.conn.recv()
                if kind == "unit":
                    self.unit, self.pending = None, []
                else:
                    self.pending.remove(k)
                    out.append((k, result))
        except Exception:  # EOF, or a message cut short by the process dying
            self.broken = True
        return out

    def exit_code(self) -> int | None:
        self.process.join(timeout=10)
        return self.process.exitcode

    def stop(self, graceful: bool) -> None:
        if graceful and self.process.is_alive():
            with contextlib.suppress(OSError):
                self.conn.send(None)
            self.process.join(timeout=10)
        if self.process.is_alive():
            self.process.terminate()
            self.process.join(timeout=5)
        if self.process.is_alive():
            self.process.kill()
            self.process.join()
        self.conn.close()


class _Pool:
    """Worker processes running units (:func:`run_in_processes`)."""

    def __init__(self, jobs: list[Job], units: list[list[int]], workers: int, policy_resolver: PolicyResolver | None,
                 done: Callable[[int, dict], None], timeout: float | None, run_unit: RunUnit):  # fmt: skip
        self.jobs, self.resolver, self.done, self.timeout = jobs, policy_resolver, done, timeout
        self.run_unit = run_unit
        self.ctx = worker_context()
        self.queue = deque(units)
        self.reasons: dict[int, list[str]] = {}
        self.workers: list[_Worker] = []
        self.workers = [_Worker(self.ctx, run_unit, policy_resolver) for _ in range(min(workers, len(units)))]

    def replace(self, i: int) -> None:
        self.workers[i].stop(graceful=False)
        self.workers[i] = _Worker(self.ctx, self.run_unit, self.resolver)

    def assign(self, i: int, unit: list[int]) -> None:
        if not self.workers[i].give(unit, self.jobs):  # it died while idle: its unit never started
            self.replace(i)
            if not self.workers[i].give(unit, self.jobs):
                raise RuntimeError(
                    f"a new benchmark worker process died at once ({_death(self.workers[i].exit_code())})"
                )

    def report(self, k: int, result: dict) -> None:
        self.done(k, {**result, "retried": self.reasons[k]} if k in self.reasons else result)

    def run(self) -> None:
        while self.queue or any(w.unit is not None for w in self.workers):
            for i, w in enumerate(self.workers):
                if w.unit is None and self.queue:
                    self.assign(i, self.queue.popleft())
            busy = [w for w in self.workers if w.unit is not None]
            wait_s = (
                None if self.timeout is None else max(0.0, min(w.since for w in busy) + self.timeout - time.monotonic())
            )
            ready = set(multiprocessing.connection.wait([w.conn for w in busy] + [w.process.sentinel for w in busy],
                                                        timeout=wait_s))  # fmt: skip
            for i, w in enumerate(self.workers):
                if w.unit is not None and (w.conn in ready or w.process.sentinel in ready):
                    self.collect(i)
                elif w.unit is not None and self.timeout is not None and time.monotonic() - w.since >= self.timeout:
                    self.time_out(i)

    def collect(self, i: int) -> None:
        """Report what worker ``i`` finished; if its process died meanwhile, its unfinished
        episodes run again (a unit's each alone; one episode in the fresh worker at once), at
        most :data:`RETRIES` times, then fail with how the process ended."""
        w = self.workers[i]
        for k, result in w.drain():
            self.report(k, result)
        if w.unit is None or (not w.broken and w.process.is_alive()):
            return
        unit, pending, why = w.unit, w.pending, _death(w.exit_code())
        self.replace(i)
        again = []
        for k in pending:
            self.reasons.setdefault(k, []).append(why)
            if len(self.reasons[k]) <= RETRIES:
                again.append(k)
            else:
                self.done(k, _lost(self.jobs[k], self.reasons[k]))
        if len(unit) == 1 and again:
            self.assign(i, again)  # again, in the fresh worker
        else:
            self.queue.extendleft([k] for k in reversed(again))

    def time_out(self, i: int) -> None:
        """Worker ``i``'s unit ran past the timeout: one episode fails (a hang would only
        repeat); a unit of several runs its unfinished episodes again, each alone."""
        w = self.workers[i]
        for k, result in w.drain():
            self.report(k, result)
        if w.unit is None:
            return
        unit, pending = w.unit, w.pending
        self.replace(i)
        if len(unit) > 1:
            self.queue.extendleft([k] for k in reversed(pending))
            return
        for k in pending:
            self.done(k, _lost(self.jobs[k], [f"timed out: still running after {self.timeout:g} s (episode timeout)"],
                               {"timed_out": True}))  # fmt: skip


def run_in_processes(
    jobs: list[Job],
    units: list[list[int]],
    workers: int,
    policy_resolver: PolicyResolver | None,
    done: Callable[[int, dict], None],
    run_unit: RunUnit,
    timeout: float | None = None,
) -> None:
    """Run ``units`` with ``run_unit`` on ``workers`` processes (:func:`worker_context`). A process that dies is
    replaced; the episodes it had not finished run again (:data:`RETRIES` times), then fail. A
    unit running longer than ``timeout`` seconds is stopped: one episode fails at once, a unit of
    several runs its unfinished episodes again, each alone."""
    pool = None
    graceful = False
    try:
        pool = _Pool(jobs, units, workers, policy_resolver, done, timeout, run_unit)
        pool.run()
        graceful = True
    finally:
        for w in pool.workers if pool is not None else []:
            w.stop(graceful)


def run_on_ray(
    jobs: list[Job],
    units: list[list[int]],
    ray_address: str,
    workers: int,
    policy_resolver: PolicyResolver | None,
    done: Callable[[int, dict], None],
    run_collected: Callable[[list[Job], PolicyResolver | None], list[dict]],
) -> None:
    """Run ``units`` as Ray tasks of ``run_collected`` (a unit's summaries in job order, the
    runner's ``run_unit_collected``). Ray runs a one-episode task whose worker died again
    (``max_retries``); one that still fails becomes a failed episode with Ray's reason. A unit of
    several that fails keeps the episodes whose logs it wrote and runs the others as tasks of one."""
    from smarts.ray_session import ray_session

    with ray_session(ray_address, num_cpus=max(2, workers)) as ray:
        single = ray.remote(max_retries=RETRIES)(run_collected)
        several = ray.remote(max_retries=0)(run_collected)
        pending: dict = {}
        reasons: dict[int, list[str]] = {}

        def submit(unit: list[int]) -> None:
            pending[(single if len(unit) == 1 else several).remote([jobs[k] for k in unit], policy_resolver)] = unit

        for unit in units:
            submit(unit)
        try:
            while pending:
                ready, _ = ray.wait(list(pending), num_returns=1)
                for ref in ready:
                    unit = pending.pop(ref)
                    try:
                        results = ray.get(ref)
                    except ray.exceptions.RayError as err:  # its worker died (Ray's retries used up) or Ray failed
                        text = str(err).strip().splitlines()
                        reason = f"Ray task failed ({type(err).__name__}: {text[0] if text else 'no message'})"
                        results = _ray_lost(jobs, unit, reason, reasons, submit)
                    for k, result in zip(unit, results):
                        if result is not None:
                            done(
                                k,
                                {**result, "retried": reasons[k]}
                                if k in reasons and "attempts" not in result
                                else result,
                            )
        except KeyboardInterrupt:
            for ref in pending:
                with contextlib.suppress(Exception):
                    ray.cancel(ref, force=True)
            raise


def _ray_lost(jobs: list[Job], unit: list[int], reason: str, reasons: dict[int, list[str]],
              submit: Callable[[list[int]], None]) -> list[dict | None]:  # fmt: skip
    """The results of a Ray task that failed: a one-episode task's episode fails; a unit of
    several keeps the episodes whose logs it wrote and submits the others alone (None here)."""
    if len(unit) == 1:
        return [{**_lost(jobs[unit[0]], [reason]), "attempts": RETRIES + 1 + len(reasons.get(unit[0], []))}]
    out: list[dict | None] = []
    for k in unit:
        out.append(finished_episode(jobs[k]))  # written before the task failed
        if out[-1] is None:
            reasons[k] = [reason]
            submit([k])
    return out
