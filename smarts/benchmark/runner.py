"""Run agents through a benchmark suite and write logs, scores and the report.

Each (agent, scenario, episode) is one job: resolve the agent's batched policy, build the scenario
with every learning (non-social) agent in the policy's own action space and controller (and the
policy's observation interface when it declares one), reset it with the episode's seed, drive
every mission vehicle with the policy, record the episode log and write it to disk at once (so
nothing is lost if a later job fails). A policy whose action space the suite does not host is an
error before any episode runs (:func:`check_agents`), never a silent conversion. Jobs run in
worker processes (libsumo allows one SUMO per process) or, with a Ray address, as Ray tasks on a
cluster (each worker needs this package installed and the output folder on a shared file
system). Results are scored by ``smarts.benchmark.metrics`` from the written logs only. An agent
that raises or returns a malformed action fails its episode with the reason recorded; the suite
goes on.

A worker process that dies (killed, out of memory, a crash in native code) loses only the episode
it was running: that episode runs once more in a fresh worker (:data:`RETRIES`), and if its worker
dies again it is recorded as a failed episode whose reason says how the process ended; the other
episodes go on. On Ray, Ray runs a task whose worker died once more, and a task that still fails
becomes a failed episode the same way. Logs are written atomically (a temporary file, then
``os.replace``), so a killed run never leaves a partial log. ``run_jobs(..., resume=True)`` skips
the episodes whose logs are already there and read back valid for the same job; Ctrl-C raises
:class:`BenchmarkInterrupted` carrying the episodes that finished.

Reference agents (:data:`REFERENCE_AGENTS`) are benchmarked beside the requested ones with the
same suite, seeds and episode count, so every report has its floor and its simple baseline.

The output folder is checked before any episode runs (:func:`check_output_folder`: it takes files
and has room for the planned logs and the report; training checks its run folder the same way),
so a read-only or full ``--out`` fails at once, naming the folder, instead of after every episode.

Agents are locators (``zoo:keep-lane``, a checkpoint path) that a policy resolver turns into
policies (``smarts.core.policies``): the installed default (the zoo), or ``policy_resolver=``
given to :func:`plan_jobs` and :func:`run_jobs` alike (a module-level function, so that worker
processes and Ray tasks receive it; it resolves the reference agents too). A policy may declare
its interface and lane-relative settings as plain data; they are validated here, before any
episode runs, with errors naming the agent, its file and the field.
"""

from __future__ import annotations

import contextlib
import dataclasses
import errno
import hashlib
import multiprocessing
import multiprocessing.connection
import os
import re
import shutil
import signal
import tempfile
import threading
import time
import traceback
from collections import deque
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from smarts.benchmark.suites import Suite, SuiteScenario, load_suite
from smarts.comms.config import CommsConfig
from smarts.core.errors import AgentSetupError, OutputError
from smarts.core.policies import Policy, PolicyResolver, resolve_policy
from smarts.core.spec import replace
from smarts.dynamics.lane_relative import LaneRelativeParams
from smarts.scenario import ACTION_SPACES, CONTROLLERS, LANE_RELATIVE_SPACES, ScenarioSpec
from smarts.sensors.interface import AgentInterface, interface_from_dict, interface_to_dict

REFERENCE_AGENTS = ("zoo:keep-lane", "zoo:random", "zoo:stand-still")
"""Benchmarked with every suite run unless asked not to: a simple baseline, chance, doing nothing."""

RETRIES = 1
"""How many times an episode whose worker process died runs again, in a fresh worker, before it is
recorded as failed (on Ray: the task's ``max_retries``)."""

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


@dataclass(frozen=True)
class PolicySetup:
    """How a policy drives: the simulator action space its actions are in, the controller that
    turns them into that space's actions, and the observation interface it reads (None: the
    scenario's)."""

    action_space: str
    controller: str = "direct"
    interface: AgentInterface | None = None
    lane_relative: LaneRelativeParams | None = None
    """The settings the policy was trained with (lane-relative controller); None: defaults."""
    comms: CommsConfig | None = None
    """The V2V settings the policy was trained with (it observes messages and sends a message part
    with each action); None: the scenario's own."""

    def to_dict(self) -> dict[str, Any]:
        return {
            "action_space": self.action_space,
            "controller": self.controller,
            "interface": None if self.interface is None else interface_to_dict(self.interface),
            "lane_relative": None if self.lane_relative is None else dataclasses.asdict(self.lane_relative),
            "comms": None
            if self.comms is None
            else {**self.comms.model_dump(), "agent_channels": dict(self.comms.agent_channels)},
        }


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


CHECKPOINT_OF_RUN = "best.pt"
"""The checkpoint a training run folder stands for when it is given as an agent: the one chosen on
held-out seeds."""

_RUN_WORDS = {"runs", "train", "evals", "eval", "benchmark"}


def is_path_locator(locator: str) -> bool:
    """Whether a locator names a file or folder (a checkpoint, a run) rather than a ``zoo:`` agent."""
    return "/" in locator or os.sep in locator or Path(locator).suffix in (".pt", ".zip") or Path(locator).is_dir()


def agent_locator(locator: str) -> str:
    """``locator`` as the runner loads it: a training run folder (``runs/train/platoon/latest``)
    becomes its :data:`CHECKPOINT_OF_RUN`; anything else is returned as given. A run folder
    without one is an ``AgentSetupError`` naming the folder and the checkpoints it does hold."""
    path = Path(locator)
    if not path.is_dir():
        return locator
    best = path / CHECKPOINT_OF_RUN
    if best.is_file():
        return str(best)
    held = sorted(p.name for p in path.glob("*.pt"))
    hint = f"it holds {', '.join(held)}: give one of them" if held else "it holds no checkpoint (*.pt)"
    raise AgentSetupError(f"agent {locator!r}: a folder without {CHECKPOINT_OF_RUN} (the checkpoint a training run "
                          f"keeps as its best on held-out seeds); {hint}")  # fmt: skip


def agent_name(locator: str) -> str:
    """How reports, plots and the viewer name an agent: a ``zoo:`` locator as it is; a checkpoint
    by its run and file (``runs/train/platoon/latest/best.pt`` -> ``platoon/003/best``: the
    ``latest`` link resolved, so two runs' checkpoints never share a name)."""
    if not is_path_locator(locator):
        return locator
    path = Path(locator)
    with contextlib.suppress(OSError):
        path = path.resolve()
    parts = [p for p in path.with_suffix("").parts[-4:] if p not in _RUN_WORDS and p != path.anchor]
    return "/".join(parts[-3:]) or locator


def agent_label(locator: str) -> str:
    """A file-system friendly form of :func:`agent_name` (log folders, TensorBoard runs)."""
    return re.sub(r"[^A-Za-z0-9_.-]+", "_", agent_name(locator)).strip("_") or "agent"


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


def benchmark_folder(suite_name: str, out: Path | None, resume: bool, root: Path = BENCHMARK_ROOT) -> tuple[Path, bool]:
    """``(folder, numbered)``: where a benchmark run writes, never over another run.

    With ``out``: that folder, refused (``OutputError``) when it already holds a run unless
    ``resume`` (which finishes it). Without: ``resume`` continues the newest numbered run of the
    suite (``<root>/<suite>/latest``); otherwise the next numbered folder, which the caller
    creates with :func:`claim_folder` once its checks pass."""
    from smarts.files import latest, next_numbered

    if out is not None:
        out = Path(out)
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


def load_policy(locator: str, seed: int = 0, policy_resolver: PolicyResolver | None = None) -> Policy:
    """The batched policy a locator names (``zoo:keep-lane``, a checkpoint file ``*.pt``), from
    ``policy_resolver`` or the installed default; seeded when it takes a seed. Unknown locators
    and unreadable checkpoints are ``ValueError``s that say why."""
    policy = resolve_policy(locator, policy_resolver)
    if hasattr(policy, "seed"):
        policy.seed(seed)
    return policy


def _who(policy: Any, locator: str) -> str:
    source = getattr(policy, "source", None)
    return f"agent {locator!r}" + (f" ({source})" if source and str(source) != locator else "")


def _interface(policy: Any, locator: str) -> AgentInterface | None:
    """The policy's interface: an ``AgentInterface``, or its plain data validated here."""
    value = getattr(policy, "interface", None)
    if value is None or isinstance(value, AgentInterface):
        return value
    try:
        return interface_from_dict(value)
    except (TypeError, ValueError) as err:
        raise AgentSetupError(f"{_who(policy, locator)}: recorded observation interface is invalid ({err})") from None


def _lane_relative(policy: Any, locator: str) -> LaneRelativeParams | None:
    """The policy's lane-relative settings: ``LaneRelativeParams``, or their plain data validated here."""
    value = getattr(policy, "lane_relative", None)
    if value is None or isinstance(value, LaneRelativeParams):
        return value
    problem = None
    known = [f.name for f in dataclasses.fields(LaneRelativeParams)]
    if not isinstance(value, dict):
        problem = f"lane_relative: expected a mapping of {', '.join(known)}, got {type(value).__name__}"
    elif unknown := sorted(set(value) - set(known)):
        problem = f"lane_relative.{unknown[0]}: unknown field; known: {', '.join(known)}"
    else:
        try:
            return LaneRelativeParams(**value)
        except (TypeError, ValueError) as err:
            problem = str(err)
    raise AgentSetupError(f"{_who(policy, locator)}: recorded lane-relative settings are invalid ({problem})")


def _comms(policy: Any, locator: str) -> CommsConfig | None:
    """The policy's V2V settings: a ``CommsConfig``, or its plain data validated here."""
    value = getattr(policy, "comms", None)
    if value is None or isinstance(value, CommsConfig):
        return value
    try:
        return CommsConfig.from_dict(value, "comms")
    except (TypeError, ValueError) as err:
        raise AgentSetupError(f"{_who(policy, locator)}: recorded V2V settings are invalid ({err})") from None


def policy_setup(policy: Policy, locator: str) -> PolicySetup:
    """Read a policy's ``action_space``, ``controller`` (default ``direct``), ``interface`` and
    ``lane_relative`` (default None; objects or their plain data, validated here);
    :class:`AgentSetupError` naming the agent when one is not valid."""
    space = getattr(policy, "action_space", None)
    if space not in ACTION_SPACES:
        raise AgentSetupError(
            f"agent {locator!r}: action_space {space!r} is not a simulator action space; expected one of {', '.join(ACTION_SPACES)}"
        )
    controller = getattr(policy, "controller", None) or "direct"
    if controller not in CONTROLLERS:
        raise AgentSetupError(f"agent {locator!r}: controller {controller!r}; expected one of {', '.join(CONTROLLERS)}")
    if controller == "lane_relative" and space not in LANE_RELATIVE_SPACES:
        raise AgentSetupError(
            f"agent {locator!r}: the lane_relative controller drives {', '.join(LANE_RELATIVE_SPACES)}, not {space!r}"
        )
    return PolicySetup(space, controller, _interface(policy, locator), _lane_relative(policy, locator),
                       _comms(policy, locator))  # fmt: skip


def check_hosted(locator: str, setup: PolicySetup, suite: Suite) -> None:
    """:class:`AgentSetupError` when ``suite`` does not host the policy's action space."""
    if setup.action_space not in suite.action_spaces:
        raise AgentSetupError(
            f"agent {locator!r} acts in action space {setup.action_space!r} (controller {setup.controller}), "
            f"which suite {suite.name!r} does not host; hosted: {', '.join(suite.action_spaces)}"
        )


def check_agents(
    agents: list[str], suite: Suite, policy_resolver: PolicyResolver | None = None
) -> dict[str, PolicySetup]:
    """Load every agent and check the suite hosts its action space, before any episode runs;
    returns each agent's setup. An unknown locator or unloadable checkpoint raises too."""
    return _checked_agents(agents, suite, policy_resolver)[0]


def _checked_agents(
    agents: list[str], suite: Suite, policy_resolver: PolicyResolver | None
) -> tuple[dict[str, PolicySetup], dict[str, str]]:
    """:func:`check_agents`, and each agent's :func:`policy_files_digest` from the same load."""
    setups, digests = {}, {}
    for locator in agents:
        policy = load_policy(locator, policy_resolver=policy_resolver)
        setup = policy_setup(policy, locator)
        check_hosted(locator, setup, suite)
        setups[locator], digests[locator] = setup, policy_files_digest(policy)
    return setups, digests


def policy_files_digest(policy: Any) -> str:
    """Content hash of the file a policy was loaded from (its ``source`` when that names a file,
    as a checkpoint policy's does, ``zoo:`` agents' included); "" for a policy of code alone. An
    updated checkpoint behind an unchanged locator changes it, so its old episodes are not reused."""
    source = getattr(policy, "source", None)
    digest = _digest_of(str(source)) if isinstance(source, (str, os.PathLike)) else b""
    return digest.hex()[:16]


def scenario_for(spec: ScenarioSpec, setup: PolicySetup) -> ScenarioSpec:
    """``spec`` with every learning (non-social) agent in the policy's action space and controller,
    and the policy's V2V settings when it was trained with its own."""
    agents = [
        a if a.is_social else replace(a, action_space=setup.action_space, controller=setup.controller)
        for a in spec.agents
    ]
    spec = replace(spec, agents=agents)
    return spec if setup.comms is None else replace(spec, comms=setup.comms)


def build_env(entry: SuiteScenario, setup: PolicySetup):
    """The env of a suite scenario for a policy: its action space, controller and interface."""
    from smarts.env import DrivingParallelEnv

    spec = scenario_for(entry.spec, setup)
    return DrivingParallelEnv(spec, observation=setup.interface, lane_relative=setup.lane_relative)


def _summary(job: Job, scenario: str, failure: str | None, info: dict) -> dict:
    return {"agent": job.agent, "scenario": scenario, "episode": job.episode, "seed": job.seed,
            "failure": failure, "log": job.log_path, **{k: info.get(k) for k in ("action_space", "controller")}}  # fmt: skip


def _digest_of(path: str) -> bytes:
    """The content hash of a file, or nothing for a locator that is not one."""
    try:
        return hashlib.sha256(Path(path).read_bytes()).digest() if Path(path).is_file() else b""
    except (OSError, ValueError):
        return b""


def job_inputs(job: Job) -> str:
    """A digest of what an episode depends on besides its seed: the suite file's contents, the
    scenario's place in it, the agent locator and the contents of the checkpoint its policy was
    loaded from (the locator's file, or a ``zoo:`` agent's: ``Job.agent_files``). Every log
    records it (``info["inputs"]``); ``resume`` reuses a log only when it matches, so a changed
    suite or a retrained or updated checkpoint is run again."""
    h = hashlib.sha256()
    own = _digest_of(job.agent)  # a locator that is a checkpoint path
    parts = [str(job.scenario_index).encode(), job.agent.encode(), _digest_of(job.suite_source), own]
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
    return _summary(job, entry.name, log.failure, info)


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
    return _summary(job, entry.name, log.failure, info)


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
    into policies (None: the installed default); give :func:`run_jobs` the same one.

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
    digests = _checked_agents(agents + extra, suite, policy_resolver)[1] if check else {}
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
    (:data:`RETRIES` times), then is recorded as failed with how the process ended (its summary
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
    episodes it finished and runs the others again, each alone."""
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

        todo = []
        for k, job in enumerate(jobs):
            if resume and not job.reuse:  # (a shared reference cache may be being written by another run)
                _remove_partial_writes(job)
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
                _run_on_ray(jobs, units, ray_address, workers, policy_resolver, done)
            elif workers <= 1 and episode_timeout is None:
                for unit in units:
                    run_unit([jobs[k] for k in unit], policy_resolver, lambda i, r, unit=unit: done(unit[i], r))
            else:
                _run_in_processes(jobs, units, max(workers, 1), policy_resolver, done, episode_timeout)
        except KeyboardInterrupt:
            raise BenchmarkInterrupted(results) from None
    return results  # type: ignore[return-value]


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
    return _summary(job, log.scenario, log.failure, info)


def _remove_partial_writes(job: Job) -> None:
    """Delete the temporary files of this job's log that a killed writer left behind."""
    from smarts.files import partial_writes

    for stale in partial_writes(job.log_path):
        stale.unlink(missing_ok=True)


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


@contextlib.contextmanager
def _sigint_deferred() -> Iterator[None]:
    """Hold Ctrl-C back while starting a worker. Blocked, not ignored: the child is born with it
    blocked (its loop then ignores it, so only the parent handles Ctrl-C and stops the workers
    instead of every worker printing a traceback), and a Ctrl-C pressed meanwhile is not lost: it
    reaches the parent as soon as the worker has started."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    if not hasattr(signal, "pthread_sigmask"):  # no signal masks (Windows): ignore it meanwhile
        before = signal.signal(signal.SIGINT, signal.SIG_IGN)
        try:
            yield
        finally:
            signal.signal(signal.SIGINT, before)
        return
    mask = signal.pthread_sigmask(signal.SIG_BLOCK, {signal.SIGINT})
    try:
        yield
    finally:
        signal.pthread_sigmask(signal.SIG_SETMASK, mask)


def _worker_loop(conn, policy_resolver: PolicyResolver | None) -> None:
    """A worker process: run the units it is sent, one at a time, until told to stop; each
    finished episode is sent at once (``("episode", k, summary)``, so a unit whose process dies
    loses only the episodes it had not finished), then ``("unit", None, None)``."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    if hasattr(signal, "pthread_sigmask"):
        signal.pthread_sigmask(signal.SIG_UNBLOCK, {signal.SIGINT})  # blocked by the parent for the start
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

    def __init__(self, ctx, policy_resolver: PolicyResolver | None):
        self.conn, child = ctx.Pipe()
        self.process = ctx.Process(target=_worker_loop, args=(child, policy_resolver), name="smarts-benchmark-worker")
        with _sigint_deferred():
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
    """Worker processes running units (:func:`_run_in_processes`)."""

    def __init__(self, jobs: list[Job], units: list[list[int]], workers: int, policy_resolver: PolicyResolver | None,
                 done: Callable[[int, dict], None], timeout: float | None):  # fmt: skip
        self.jobs, self.resolver, self.done, self.timeout = jobs, policy_resolver, done, timeout
        self.ctx = multiprocessing.get_context("spawn")
        self.queue = deque(units)
        self.reasons: dict[int, list[str]] = {}
        self.workers: list[_Worker] = []
        self.workers = [_Worker(self.ctx, policy_resolver) for _ in range(min(workers, len(units)))]

    def replace(self, i: int) -> None:
        self.workers[i].stop(graceful=False)
        self.workers[i] = _Worker(self.ctx, self.resolver)

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


def _run_in_processes(
    jobs: list[Job],
    units: list[list[int]],
    workers: int,
    policy_resolver: PolicyResolver | None,
    done: Callable[[int, dict], None],
    timeout: float | None = None,
) -> None:
    """Run ``units`` on ``workers`` spawned processes. A process that dies is replaced; the
    episodes it had not finished run again (:data:`RETRIES` times), then fail. A unit running
    longer than ``timeout`` seconds is stopped: one episode fails at once, a unit of several runs
    its unfinished episodes again, each alone."""
    pool = None
    graceful = False
    try:
        pool = _Pool(jobs, units, workers, policy_resolver, done, timeout)
        pool.run()
        graceful = True
    finally:
        for w in pool.workers if pool is not None else []:
            w.stop(graceful)


def _run_on_ray(
    jobs: list[Job],
    units: list[list[int]],
    ray_address: str,
    workers: int,
    policy_resolver: PolicyResolver | None,
    done: Callable[[int, dict], None],
) -> None:
    """Run ``units`` as Ray tasks. Ray runs a one-episode task whose worker died again
    (``max_retries``); one that still fails becomes a failed episode with Ray's reason. A unit of
    several that fails keeps the episodes whose logs it wrote and runs the others as tasks of one."""
    from smarts.ray_session import ray_session

    with ray_session(ray_address, num_cpus=max(2, workers)) as ray:
        single = ray.remote(max_retries=RETRIES)(run_unit_collected)
        several = ray.remote(max_retries=0)(run_unit_collected)
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


# ---------------------------------------------------------------------------------- batched units
MAX_BATCH = 64
"""Most episodes in one unit (one simulation): past a few dozen, a bigger batch gains little per
step while it waits longer for its longest episode."""


def plan_units(
    jobs: list[Job], todo: list[int], workers: int = 1, policy_resolver: PolicyResolver | None = None
) -> list[list[int]]:
    """``todo`` (job indices) as units: the episodes of one agent (and step length) that can share
    a simulation, in job order, at most :data:`MAX_BATCH` each, split further until there are
    ``workers`` units to run at once; every other episode a unit of its own."""
    from smarts.benchmark.batched import batching_mode, solo_reason

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
                groups.setdefault((agent, source, spec.step_length), []).append(k)
            else:
                units.append([k])
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
    bit for bit on the whole adaptive suite.)"""
    import torch

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
    """Run ``jobs[todo]`` (one agent) in simulations of many episodes (one per step length);
    returns those that must run alone."""
    from smarts.benchmark.batched import BatchEpisode, batching_mode, run_batch, solo_reason

    first = jobs[todo[0]]
    try:
        suite = load_suite(first.suite_source)
        policy = load_policy(first.agent, first.seed, policy_resolver)
        setup = policy_setup(policy, first.agent)
        check_hosted(first.agent, setup, suite)
        mode = batching_mode(policy)
    except Exception:  # noqa: BLE001 - alone, each episode records why
        return todo
    if mode is None:
        return todo
    alone, by_step = [], {}
    for i in todo:
        job = jobs[i]
        entry = suite.scenarios[job.scenario_index]
        spec = scenario_for(entry.spec, setup)
        if solo_reason(spec, setup.interface) is not None:
            alone.append(i)
            continue
        try:
            own = load_policy(job.agent, job.seed, policy_resolver) if mode == "instances" else None
        except Exception:  # noqa: BLE001
            alone.append(i)
            continue
        meta = dict(scenario=entry.name, task=suite.task, episode=job.episode, seed=job.seed,
                    time_limit=entry.time_limit, follow=entry.follow, info={**_episode_info(job, suite), **setup.to_dict()})  # fmt: skip
        by_step.setdefault(spec.step_length, []).append((i, BatchEpisode(spec, job.seed, meta, own)))
    for members in by_step.values():
        index = [i for i, _ in members]

        def finished(b: int, log, index=index) -> None:
            report(index[b], _write_batched(jobs[index[b]], log))

        alone += [index[b] for b in run_batch([e for _, e in members], policy, mode, setup.interface,
                                              setup.lane_relative, finished)]  # fmt: skip
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
    return _summary(job, log.scenario, log.failure, log.info)
