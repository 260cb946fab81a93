"""What a benchmark run is to do and where it writes: jobs, units, cache keys, output folders.

Each (agent, scenario, episode) is one :class:`Job` (:func:`plan_jobs`); the episodes of an agent
that can share a simulation are grouped into units (:func:`plan_units`). The output folder is
checked before any episode runs (:func:`check_output_folder`: it takes files and has room for the
planned logs and the report; training checks its run folder the same way), so a read-only or full
``--out`` fails at once, naming the folder, instead of after every episode. A job's log records a
digest of its inputs (:func:`job_inputs`), so ``resume`` reuses only the logs of the same job
(:func:`finished_episode`); a job that cannot run gets a log saying why
(:func:`write_failed_episode`). Apart from the episode loop and the worker pool, which both use it.
"""

from __future__ import annotations

import errno
import hashlib
import os
import shutil
import tempfile
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from smarts.benchmark.agents import (
    REFERENCE_AGENTS,
    agent_label,
    file_digest,
    load_policy,
    policy_setup,
    scenario_for,
    setups_and_digests,
)
from smarts.benchmark.suites import Suite, load_suite
from smarts.core.errors import OutputError
from smarts.core.policies import PolicyResolver

REPORT_BYTES = 32 * 2**20
"""Free space a benchmark report needs (results, plots, TensorBoard events) besides its logs."""
EPISODE_LOG_BYTES = 256 * 2**10
"""Free space reserved per planned episode log (a few seconds of a few agents take tens of kB)."""


def check_output_folder(folder: str | os.PathLike, need_bytes: int, what: str = "output folder") -> None:
    """Fail fast, before a run starts: ``folder`` (or, when it does not exist yet, the nearest
    existing folder above it, where it will be made) must take a new file and have ``need_bytes``
    free on its disk. :class:`OutputError` naming ``folder`` otherwise; nothing is left behind.

    Writability is tried with a real file, not judged from permission bits (which do not bind
    every user, and say nothing of a read-only file system)."""
    folder = Path(folder)
    base = folder
    while not base.exists() and not base.is_symlink() and base.parent != base:
        base = base.parent
    if not base.is_dir():
        raise OutputError(f"{what} {folder}: cannot be made there: {base} is not a folder")
    try:
        fd, probe = tempfile.mkstemp(prefix=".write-check-", dir=base)
        os.close(fd)
        os.unlink(probe)
    except OSError as err:
        why = "its file system is read-only" if err.errno == errno.EROFS else (err.strerror or str(err)).lower()
        raise OutputError(
            f"{what} {folder}: cannot write there ({why}); give a folder this user can write to"
        ) from None
    free = shutil.disk_usage(base).free
    if free < need_bytes:
        raise OutputError(f"{what} {folder}: {free / 2**20:.0f} MiB free on its disk; the run needs about "
                          f"{need_bytes / 2**20:.0f} MiB: free some space or give a folder on another disk")  # fmt: skip


@dataclass(frozen=True)
class Job:
    agent: str
    suite_source: str
    scenario_index: int
    episode: int
    seed: int
    log_path: str
    reuse: bool = False
    """Reuse ``log_path`` when it already holds a readable log (cached reference episodes)."""
    agent_files: str = ""
    """Content hash of the files the agent's policy was loaded from (:func:`policy_files_digest`:
    the checkpoint of a ``zoo:`` agent or of a path), part of :func:`job_inputs`."""


# ---------------------------------------------------------------------------------- output folders
BENCHMARK_ROOT = Path("runs") / "benchmark"
"""Where ``python -m train benchmark`` puts a suite's runs by default: ``<root>/<suite>/001``, ..."""


def holds_benchmark_run(folder: Path) -> bool:
    """Whether ``folder`` already holds a benchmark run (its report, results or episode logs)."""
    folder = Path(folder)
    if any((folder / name).exists() for name in ("report.md", "results.json", "results.csv")):
        return True
    logs = folder / "logs"
    return logs.is_dir() and any(logs.rglob("*.npz"))


PACKAGE_NAMES = ("smarts", "agents", "zoo", "train")
"""The project's top-level packages: an output folder of one of these names in the current
directory would be imported in their place (Python looks in the current directory first)."""


def benchmark_folder(suite_name: str, out: Path | None, resume: bool, root: Path = BENCHMARK_ROOT) -> tuple[Path, bool]:
    """``(folder, numbered)``: where a benchmark run writes, never over another run.

    With ``out``: that folder, refused (``OutputError``) when it already holds a run unless
    ``resume`` (which finishes it). Without: ``resume`` continues the newest numbered run of the
    suite (``<root>/<suite>/latest``); otherwise the next numbered folder, which the caller
    creates with :func:`claim_folder` once its checks pass."""
    from smarts.files import latest, next_numbered

    if out is not None:
        out = Path(out)
        if out.name in PACKAGE_NAMES and out.resolve().parent == Path.cwd().resolve():
            raise OutputError(
                f"output folder {out}: a folder named {out.name!r} in the current directory hides the installed "
                f"package {out.name!r} from `python -m` (the workers load the agents through it); give another "
                f"name, e.g. runs/{out.name}"
            )
        if not resume and holds_benchmark_run(out):
            raise OutputError(f"output folder {out}: already holds a benchmark run (report.md, results, logs); "
                              "give another --out, or add --resume to finish that run")  # fmt: skip
        return out, False
    suite_root = Path(root) / suite_name
    if resume:
        found = latest(suite_root)
        if found is None:
            raise OutputError(f"--resume: no benchmark run of suite {suite_name!r} under {suite_root} "
                              "(it has no 'latest'); give the run's folder with --out")  # fmt: skip
        return found, False
    return next_numbered(suite_root), True


def claim_folder(folder: Path, numbered: bool) -> Path:
    """Create the run folder. A numbered one is taken with an exclusive ``mkdir`` (two runs
    started at once get two folders: the later one moves on to the next number) and
    ``latest`` then points to it."""
    from smarts.files import next_numbered, point_latest

    folder = Path(folder)
    if not numbered:
        folder.mkdir(parents=True, exist_ok=True)
        return folder
    folder.parent.mkdir(parents=True, exist_ok=True)
    for _ in range(1000):
        try:
            folder.mkdir()
            break
        except FileExistsError:
            folder = next_numbered(folder.parent)
    point_latest(folder.parent, folder)
    return folder


def episode_summary(job: Job, scenario: str, failure: str | None, info: dict) -> dict:
    return {"agent": job.agent, "scenario": scenario, "episode": job.episode, "seed": job.seed,
            "failure": failure, "log": job.log_path, **{k: info.get(k) for k in ("action_space", "controller")}}  # fmt: skip


def job_inputs(job: Job) -> str:
    """A digest of what an episode depends on besides its seed: the suite file's contents, the
    scenario's place in it, the agent locator and the contents of the checkpoint its policy was
    loaded from (the locator's file, or a ``zoo:`` agent's: ``Job.agent_files``). Every log
    records it (``info["inputs"]``); ``resume`` reuses a log only when it matches, so a changed
    suite or a retrained or updated checkpoint is run again."""
    h = hashlib.sha256()
    own = file_digest(job.agent)  # a locator that is a checkpoint path
    parts = [str(job.scenario_index).encode(), job.agent.encode(), file_digest(job.suite_source), own]
    if job.agent_files and not own:  # a zoo: agent's checkpoint (code-only agents keep their keys)
        parts.append(job.agent_files.encode())
    for part in parts:
        h.update(part + b"\0")
    return h.hexdigest()[:16]


def write_failed_episode(job: Job, reason: str, info: dict[str, Any] | None = None) -> dict:
    """Write a log that records job's episode as failed with ``reason`` (scored as the metrics
    config's ``failed_episodes`` says) and return its summary."""
    from smarts.benchmark.metrics import EpisodeLog, write_episode

    suite = load_suite(job.suite_source)
    entry = suite.scenarios[job.scenario_index]
    info = {"agent": job.agent, "inputs": job_inputs(job), **(info or {})}
    log = EpisodeLog(
        scenario=entry.name, task=suite.task, episode=job.episode, seed=job.seed,
        dt=entry.spec.step_length, time_limit=entry.time_limit, goal_radius=0.0, agents={},
        initial_route_distance={}, failure=reason, info=info,
    )  # fmt: skip
    write_episode(log, Path(job.log_path))
    return episode_summary(job, entry.name, log.failure, info)


def reference_cache_key(suite: Suite, seed: int) -> str:
    """Folder name of a suite's cached reference episodes: the suite's name, first seed and a hash
    of its file and of the reference agents' code (a changed suite or agent is a new folder)."""
    digest = hashlib.sha256(Path(suite.source).read_bytes() if suite.source else suite.name.encode())
    root = Path(__file__).resolve().parents[2]
    for module in ("agents/keep_lane.py", "agents/random_agent.py", "agents/stand_still.py", "zoo/registry.py"):
        path = root / module
        if path.is_file():
            digest.update(path.read_bytes())
    return f"{suite.name}-seed{seed}-{digest.hexdigest()[:12]}"


def plan_jobs(
    agents: list[str],
    suite: Suite,
    episodes: int,
    out_dir: Path,
    seed: int | None = None,
    *,
    references: bool = True,
    reference_cache: Path | None = None,
    check: bool = True,
    policy_resolver: PolicyResolver | None = None,
) -> list[Job]:
    """One job per (agent, scenario, episode); episode ``e`` of every scenario has seed
    ``seed + e`` (``seed`` defaults to the suite's).

    ``references``: add the :data:`REFERENCE_AGENTS` not already requested, with the same
    scenarios, seeds and episodes. ``reference_cache``: a folder where reference episodes are
    kept and reused when already there (keyed by :func:`reference_cache_key`; for repeated
    evaluations during training; the logs do not depend on the agent under test). ``check``:
    load every agent and refuse one whose action space the suite does not host
    (:func:`check_agents`) before any job exists. ``policy_resolver``: turns the agents' locators
    into policies (None: the installed default); give ``run_jobs`` the same one.

    ``out_dir`` (and ``reference_cache``) must take files and have room for the report and
    :data:`EPISODE_LOG_BYTES` per episode: ``OutputError`` naming the
    folder before any episode runs otherwise. Each job carries the content hash of its agent's
    checkpoint (``Job.agent_files``, when ``check`` loads the agents), so ``resume`` runs an
    updated checkpoint's episodes again."""
    base = suite.seed if seed is None else seed
    out_dir = Path(out_dir)
    agents = list(agents)
    extra = [a for a in REFERENCE_AGENTS if a not in agents] if references else []
    planned = len(agents + extra) * len(suite.scenarios) * episodes
    check_output_folder(out_dir, REPORT_BYTES + planned * EPISODE_LOG_BYTES)
    if reference_cache is not None:
        check_output_folder(reference_cache, len(REFERENCE_AGENTS) * len(suite.scenarios) * episodes * EPISODE_LOG_BYTES,
                            "reference cache")  # fmt: skip
    digests = setups_and_digests(agents + extra, suite, policy_resolver)[1] if check else {}
    cache = Path(reference_cache) / reference_cache_key(suite, base) if reference_cache is not None else None
    jobs = []
    for agent in agents + extra:
        reuse = cache is not None and agent in REFERENCE_AGENTS
        root = cache if reuse else out_dir / "logs"
        for i, scenario in enumerate(suite.scenarios):
            for episode in range(episodes):
                path = root / agent_label(agent) / scenario.name / f"episode_{episode:03d}.npz"
                jobs.append(
                    Job(agent, suite.source, i, episode, base + episode, str(path), reuse, digests.get(agent, ""))
                )
    return jobs


def finished_episode(job: Job) -> dict | None:
    """The summary of job's episode when its log is already on disk, reads back valid and was
    written for this job (agent, episode, seed, :func:`job_inputs`); None when it must run (no
    log, a corrupt or partial one, another job's, or an episode lost to a dead worker)."""
    from smarts.benchmark.metrics import read_episode

    path = Path(job.log_path)
    if not path.is_file():
        return None
    try:
        log = read_episode(path)
    except Exception:
        return None  # unreadable or invalid: run it again
    info = log.info or {}
    if log.seed != job.seed or log.episode != job.episode or info.get("agent", job.agent) != job.agent:
        return None
    if "inputs" in info and info["inputs"] != job_inputs(job):
        return None  # the suite or the checkpoint changed since
    if info.get("worker_died"):
        return None  # lost to the machinery, not the agent: give it another chance
    return episode_summary(job, log.scenario, log.failure, info)


def remove_partial_writes(job: Job) -> None:
    """Delete the temporary files of this job's log that a killed writer left behind."""
    from smarts.files import partial_writes

    for stale in partial_writes(job.log_path):
        stale.unlink(missing_ok=True)


# ---------------------------------------------------------------------------------- batched units
MAX_BATCH = 256
"""Most episodes in one unit (one simulation). A bigger batch shares the per-step fixed costs
(the Python of each stage, the policies' calls) among more episodes, but it steps the traffic of
episodes that are over until its longest one ends. Measured on the adaptive suite's three
reference agents (165 episodes, one process): one simulation of all 165 took 4.9 s of CPU,
three of 64, 64 and 37 took 5.6-6.0 s."""


def plan_units(
    jobs: list[Job], todo: list[int], workers: int = 1, policy_resolver: PolicyResolver | None = None
) -> list[list[int]]:
    """``todo`` (job indices) as units: the episodes that can share a simulation (of agents whose
    policies drive alike: the same action space, controller and observation interface; and of one
    step length), in job order, at most :data:`MAX_BATCH` each, split further until there are
    ``workers`` units to run at once; every other episode a unit of its own."""
    from smarts.benchmark.batching import batching_mode, solo_reason

    groups: dict[tuple, list[int]] = {}
    units: list[list[int]] = []
    for (agent, source), ks in _by_agent(jobs, todo).items():
        try:
            policy = load_policy(agent, policy_resolver=policy_resolver)
            setup = policy_setup(policy, agent)
            suite = load_suite(source)
        except Exception:  # noqa: BLE001 - each episode reports it
            units += [[k] for k in ks]
            continue
        if batching_mode(policy) is None:
            units += [[k] for k in ks]
            continue
        for k in ks:
            spec = scenario_for(suite.scenarios[jobs[k].scenario_index].spec, setup)
            if solo_reason(spec, setup.interface) is None:
                groups.setdefault((source, spec.step_length, repr(setup)), []).append(k)
            else:
                units.append([k])
    groups = {key: sorted(ks) for key, ks in groups.items()}
    batches = [ks[i : i + MAX_BATCH] for ks in groups.values() for i in range(0, len(ks), MAX_BATCH)]
    while batches and len(units) + len(batches) < workers and max(map(len, batches)) > 1:
        big = max(batches, key=len)
        batches.remove(big)
        batches += [big[: len(big) // 2], big[len(big) // 2 :]]
    return sorted(batches + units, key=lambda unit: unit[0])


def _by_agent(jobs: list[Job], todo: list[int]) -> dict[tuple[str, str], list[int]]:
    out: dict[tuple[str, str], list[int]] = {}
    for k in todo:
        out.setdefault((jobs[k].agent, jobs[k].suite_source), []).append(k)
    return out
