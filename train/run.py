"""What every training run is, whichever library trains it (``train.ppo``: TorchRL, ``train.sb3_ppo``: SB3).

A run owns its folder ``out``::

    config.json        the run's settings
    tensorboard/       one event stream: SCALAR_TAGS after every batch, eval/* and eval_trajectories/*
                       at every evaluation, eval/best_S_bench when a periodic evaluation is the best
    last.pt            after every batch (collection + update)
    best.pt            the evaluated checkpoint with the highest S_bench on held-out seeds
    final.pt           at the end, then evaluated into eval/
    interrupted.pt     on Ctrl-C
    evals/step_N/      the report of the evaluation every ``eval_every`` steps
    eval/              the report of the final evaluation

SB3 runs also write ``<name>_sb3.zip`` beside every ``<name>.pt``: SB3's own save, which
``stable_baselines3.PPO.load`` reads (the ``.pt`` files are what the benchmark and ``--resume``
read, with ``torch.load(..., weights_only=True)``).

A folder that holds a run is never written over: only ``--resume`` of one of its own checkpoints
continues in it. A checkpoint to resume from is checked against the run's settings (library, action
space, controller, observation, network, lane-relative settings, step) before anything is built or
written. At the end the trainer prints a JSON summary with the keys SUMMARY_KEYS (null where a
value is not known, e.g. no episode ended in the last batch), then the final evaluation's eval/*.
"""

from __future__ import annotations

import copy
import dataclasses
import json
import math
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Callable

import numpy as np
import torch

from agents.checkpoint import CheckpointError, checkpoint_format, read_checkpoint
from agents.ppo import CHECKPOINT_FORMAT, check_checkpoint
from agents.sb3_policy import SB3_FORMAT, check_export
from smarts.core.spec import replace
from smarts.files import atomic_write_text, next_numbered, point_latest
from train.config import ACTION_SPACES, TASK_SUITE, TrainConfig

SCALAR_TAGS = (
    "episode/return",  # mean return (in the reward's own units) of the episodes that ended in the batch
    "episode/length",
    "loss/objective",  # the clipped surrogate
    "loss/critic",  # weighted by critic_coeff
    "loss/entropy",  # -entropy_coeff * entropy
    "policy/entropy",
    "policy/kl_approx",  # E[(r - 1) - log r] over the update's minibatches: never negative
    "policy/clip_fraction",  # share of the samples whose probability ratio the clip cut
    "policy/action_std",  # relative to half the action range
    "train/explained_variance",  # of the value targets by the critic (1: perfect, 0: no better than their mean)
    "train/grad_norm",  # gradient norm before clipping to max_grad_norm, mean over the update
    "train/lr",
    "perf/env_steps_per_s",  # agent steps per second since the start, evaluations included
    "perf/update_s",  # seconds of the batch's PPO update
)
"""The TensorBoard scalars both trainers log after every batch (each may log more of its own)."""
SUMMARY_KEYS = ("steps", "wall_s", *SCALAR_TAGS)
CHECKPOINTS = ("last", "best", "final", "interrupted")
LIBRARY_OF_FORMAT = {CHECKPOINT_FORMAT: "torchrl", SB3_FORMAT: "sb3"}
TRAIN_SEED_BASE = 100_000
"""Training episodes use seeds from here up (``seed * 1_000_003`` further on); evaluation uses
``eval_seed`` and the benchmark suites their own seeds, so neither is seen in training."""

RUN_FREE_BYTES = 128 * 2**20
"""Free space a run folder must have when training starts: checkpoints (with the optimiser's state),
TensorBoard events and the held-out evaluations' logs, plots and videos."""

Save = Callable[[Path], Path]
"""A trainer's ``save(path) -> path``: its checkpoint of the current step and metrics."""


# ------------------------------------------------------------------ batches and progress
@dataclass(frozen=True)
class BatchPlan:
    """How a run's steps fall into batches, the same for both libraries: every batch but the last
    takes ``first_steps`` steps of every one of ``slots`` slots (``frames_per_batch`` rounded up to
    whole steps of every slot), the last only what ``total_steps`` still needs, so a run ends less
    than one step of every slot past ``total_steps`` (``whole``: the last is a full batch too,
    for collectors whose batch size is fixed)."""

    batches: int
    first_steps: int
    last_steps: int
    slots: int

    @classmethod
    def of(cls, remaining: int, frames_per_batch: int, slots: int, whole: bool = False) -> "BatchPlan":
        per = max(1, -(-frames_per_batch // slots))
        rows = max(1, -(-remaining // slots))  # steps of every slot still to take
        batches = -(-rows // per)
        return cls(batches, per, per if whole else rows - (batches - 1) * per, slots)

    def steps_per_batch(self):
        """Steps of every slot in each batch, in order."""
        for b in range(self.batches):
            yield self.last_steps if b == self.batches - 1 else self.first_steps

    @property
    def frames(self) -> int:
        return ((self.batches - 1) * self.first_steps + self.last_steps) * self.slots


def _clock(seconds: float) -> str:
    seconds = int(max(seconds, 0))
    return f"{seconds // 3600}:{seconds // 60 % 60:02d}:{seconds % 60:02d}"


class Progress:
    """A run's progress: rich's bar when stdout is a terminal, else one plain line per batch (a
    cluster job's log reads them as they come); nothing when ``enabled`` is false (``--quiet``)."""

    def __init__(self, title: str, total: int, step: int = 0, enabled: bool = True):
        import sys

        self.title, self.total, self.first = title, total, step
        self.start = time.perf_counter()
        self.enabled = enabled
        self.bar = None
        if enabled and sys.stdout.isatty():
            from rich.progress import Progress as Bar

            self.bar = Bar()
            self.bar.start()
            self.task = self.bar.add_task(title, total=total, completed=step)

    def line(self, step: int, metrics: dict) -> str:
        """The plain line of a batch: steps, share, rate, return, the last held-out score, time."""
        elapsed = time.perf_counter() - self.start
        rate = (step - self.first) / max(elapsed, 1e-9)
        eta = (self.total - step) / rate if rate > 0 else float("nan")
        parts = [f"{self.title}: {step:,}/{self.total:,} steps ({100.0 * min(step / self.total, 1.0):.0f}%)",
                 f"{rate:,.0f} env-steps/s"]  # fmt: skip
        if math.isfinite(metrics.get("episode/return", float("nan"))):
            parts.append(f"return {metrics['episode/return']:.1f}")
        if "eval/S_bench" in metrics:
            parts.append(f"held-out S_bench {metrics['eval/S_bench']:.3f}")
        parts.append(f"elapsed {_clock(elapsed)}" + (f", left {_clock(eta)}" if math.isfinite(eta) else ""))
        return " | ".join(parts)

    def update(self, step: int, metrics: dict) -> None:
        if not self.enabled:
            return
        if self.bar is not None:
            ret = metrics.get("episode/return", float("nan"))
            self.bar.update(self.task, completed=min(step, self.total), description=f"{self.title} return {ret:.1f}")
        else:
            print(self.line(step, metrics), flush=True)

    def close(self) -> None:
        if self.bar is not None:
            self.bar.stop()
            self.bar = None


class Bar:
    """A counting bar on rich (the project's one progress-bar library) for the planners' trainers
    and data generators: ``Bar(iterable)`` or ``Bar(total=n)`` with ``update``, ``set_postfix``,
    ``close`` and ``Bar.write`` for a line above it; ``disable`` shows nothing."""

    def __init__(self, iterable=None, total: int | None = None, desc: str = "", disable: bool = False):
        from rich.progress import Progress as RichProgress

        self.iterable, self.desc = iterable, desc
        if total is None and iterable is not None and hasattr(iterable, "__len__"):
            total = len(iterable)
        self.bar = None if disable else RichProgress()
        if self.bar is not None:
            self.bar.start()
            self.task = self.bar.add_task(desc, total=total)

    def __iter__(self):
        try:
            for item in self.iterable:
                yield item
                self.update(1)
        finally:
            self.close()

    def update(self, n: int = 1) -> None:
        if self.bar is not None:
            self.bar.advance(self.task, n)

    def set_postfix(self, **values) -> None:
        if self.bar is not None:
            shown = ", ".join(f"{k}={v}" for k, v in values.items())
            self.bar.update(self.task, description=f"{self.desc} {shown}")

    def close(self) -> None:
        if self.bar is not None:
            self.bar.stop()
            self.bar = None

    @staticmethod
    def write(text: str) -> None:
        """A line of its own (rich keeps a live bar below what is printed)."""
        print(text, flush=True)


# ------------------------------------------------------------------ what a run trains on
def scenario_names(names: list[str]) -> list[str]:
    """``suite:*`` expanded to every scenario of that suite, in suite order."""
    from smarts.benchmark.suites import load_suite

    out = []
    for name in names:
        if name.endswith(":*"):
            out += [f"{name[:-2]}:{s.name}" for s in load_suite(name[:-2]).scenarios]
        else:
            out.append(name)
    return out


def training_spec(name, action_space: str, controller: str = "direct", comms=None):
    """A scenario spec from ``suite:scenario``, a library name or a spec, every learning agent on
    ``action_space`` driven through ``controller`` (social agents keep their own), with ``comms``
    (a ``CommsConfig``) instead of the scenario's own V2V settings when given."""
    from smarts.benchmark.suites import load_suite
    from smarts.scenario import load_scenario

    if not isinstance(name, str):
        spec = name
    elif ":" in name:
        suite_name, scenario = name.split(":", 1)
        suite = load_suite(suite_name)
        matches = [s.spec for s in suite.scenarios if s.name == scenario]
        if not matches:
            raise ValueError(f"suite {suite_name!r} has no scenario {scenario!r}")
        spec = matches[0]
    else:
        spec = load_scenario(name)
    agents = [
        a if a.is_social else replace(a, action_space=ACTION_SPACES[action_space], controller=controller)
        for a in spec.agents
    ]
    spec = replace(spec, agents=agents)
    return spec if comms is None else replace(spec, comms=comms)


def training_specs(cfg: TrainConfig) -> list:
    """The ``envs`` scenario copies, cycling through the task's scenarios (each scenario read and
    validated once; every copy gets its own deep copy of the spec)."""
    names = scenario_names(cfg.scenarios)
    built: dict[str, object] = {}
    specs = []
    for i in range(cfg.envs):
        name = names[i % len(names)]
        if name not in built:
            built[name] = training_spec(name, cfg.action_space, cfg.controller, cfg.comms_config())
        specs.append(copy.deepcopy(built[name]))
    return specs


def initial_log_std(values: list[float], size: int) -> list[float]:
    """One initial log std per action component: one value for all, one per component, or one per
    driving component, the message part of a V2V action (which follows them) taking the last."""
    if len(values) > size:
        raise ValueError(f"init_log_std: expected at most {size} values (one per action component), got {values}")
    return list(values) + [values[-1]] * (size - len(values))


def interface_dict(cfg: TrainConfig) -> dict:
    """The observation interface as the plain data checkpoints record."""
    from smarts.sensors.interface import interface_to_dict

    return interface_to_dict(cfg.observation_interface())


def comms_dict(cfg: TrainConfig) -> dict | None:
    """The V2V settings as checkpoints record them (None: the scenarios' own)."""
    config = cfg.comms_config()
    return None if config is None else {**config.model_dump(), "agent_channels": dict(config.agent_channels)}


def lane_relative_dict(cfg: TrainConfig) -> dict | None:
    """The lane-relative settings as checkpoints record them (None for direct actions)."""
    if cfg.controller != "lane_relative":
        return None
    return dataclasses.asdict(cfg.lane_relative_params())


# ------------------------------------------------------------------ resuming
def check_run_folder(out: Path) -> None:
    """Before anything is built: the run folder (or where it will be made) takes files and has
    :data:`RUN_FREE_BYTES` free; ``OutputError`` naming it otherwise (fail fast, not mid-run)."""
    from smarts.benchmark.jobs import check_output_folder

    check_output_folder(out, RUN_FREE_BYTES, "run folder")


def run_folder(cfg: TrainConfig, resume: Path | None = None) -> Path:
    """The folder a run writes to: ``out`` when given; else the resumed checkpoint's folder; else
    the next numbered folder under ``runs_dir`` (``001``, ``002``, ...). Nothing is created here:
    :class:`Run` creates it once the setup has been checked, and points ``runs_dir/latest`` to it."""
    if cfg.out:
        return Path(cfg.out)
    if resume is not None:
        return Path(resume).parent
    return next_numbered(cfg.runs_dir)


def checkpoint_setup(blob: dict) -> dict:
    """What a checkpoint was trained with, in the terms ``check_resume`` compares."""
    library = LIBRARY_OF_FORMAT[checkpoint_format(blob)]
    return {
        "action space": blob["action"]["space"],
        "controller": blob["action"].get("controller", "direct"),
        "observation interface": blob.get("interface"),
        "hidden layers": list(blob["net_arch"] if library == "sb3" else blob["hidden"]),
        "lane-relative settings": blob.get("lane_relative"),
    }


def config_setup(cfg: TrainConfig) -> dict:
    return {
        "action space": ACTION_SPACES[cfg.action_space],
        "controller": cfg.controller,
        "observation interface": interface_dict(cfg),
        "hidden layers": list(cfg.hidden),
        "lane-relative settings": lane_relative_dict(cfg),
    }


def check_resume(path: Path, cfg: TrainConfig) -> dict:
    """The checkpoint to resume from, refused (before any env is built or file written) when it was
    written by the other library or trained for another action space, controller, observation,
    network or lane-relative settings, or when it already has ``total_steps``."""
    path = Path(path)
    blob = read_checkpoint(path)
    library = LIBRARY_OF_FORMAT.get(checkpoint_format(blob))
    if library is None:
        found = checkpoint_format(blob) or type(blob).__name__
        raise CheckpointError(
            f"{path}: expected a checkpoint of format {' or '.join(LIBRARY_OF_FORMAT)}, found {found!r}"
        )
    if library != cfg.lib:
        raise CheckpointError(f"{path}: trained with library {library!r}; this run uses {cfg.lib!r}")
    if library == "torchrl":
        check_checkpoint(blob, path)
    else:
        check_export(blob, str(path))
    theirs = checkpoint_setup(blob)
    for what, value in config_setup(cfg).items():
        if theirs[what] != value:
            raise CheckpointError(f"{path}: trained with {what} {theirs[what]!r}; this run uses {value!r}")
    if int(blob["step"]) >= cfg.total_steps:
        raise ValueError(f"{path}: already at {int(blob['step'])} steps; raise --total-steps to continue")
    return blob


# ------------------------------------------------------------------ the run
class Run:
    """A run's folder, TensorBoard writer, checkpoints and held-out evaluations, for either trainer.

    The trainer calls ``end_of_batch`` after every update, ``interrupted`` on Ctrl-C and ``finish``
    at the end, each with its own ``save(path)``."""

    def __init__(self, cfg: TrainConfig, out: Path, resume: Path | None = None, progress: bool = False):
        from torch.utils.tensorboard import SummaryWriter

        out = Path(out)
        held = [n for n in ("config.json", *(f"{c}.pt" for c in CHECKPOINTS)) if (out / n).exists()]
        continuing = resume is not None and Path(resume).resolve().parent == out.resolve()
        if held and not continuing:
            raise ValueError(f"{out} already holds a training run ({', '.join(held)}): give another --out-dir, "
                             f"or continue it with --resume {out / 'last.pt'}")  # fmt: skip
        check_run_folder(out)
        self.cfg, self.out = cfg, out
        self.progress = progress  # a bar for the final evaluation (periodic ones run under training's bar)
        out.mkdir(parents=True, exist_ok=True)
        if out.name.isdigit() and out.parent.resolve() == Path(cfg.runs_dir).resolve():
            point_latest(out.parent, out)  # a numbered run: runs_dir/latest -> this one
        config = json.dumps(cfg.model_dump(), indent=2)
        atomic_write_text(out / "config.json", config)
        self.writer = SummaryWriter(log_dir=str(out / "tensorboard"))
        if not continuing:  # the settings beside the curves (TensorBoard's Text tab), as config.json holds them
            self.writer.add_text("config", "```\n" + config + "\n```", 0)
        # Where to look, before the first batch (a job's log shows it at once).
        print(f"run folder: {out}\nTensorBoard: tensorboard --logdir {out / 'tensorboard'}", flush=True)
        self.best_score = -np.inf
        if continuing and (out / "best.pt").is_file():  # a resumed run keeps its selection
            recorded = read_checkpoint(out / "best.pt").get("metrics", {})
            self.best_score = recorded.get("eval/S_bench", -np.inf)

    def log(self, metrics: dict, step: int) -> None:
        for name, value in metrics.items():
            if np.isfinite(value):
                self.writer.add_scalar(name, value, step)

    def end_of_batch(self, step: int, batch_steps: int, metrics: dict, save: Save) -> None:
        """Log the batch's ``metrics``, write ``last.pt`` and, every ``eval_every`` steps (but for
        the last one, which ``finish`` evaluates), evaluate it on held-out seeds, keeping the best."""
        self.log(metrics, step)
        last = save(self.out / "last.pt")
        cfg = self.cfg
        periodic = cfg.eval_every and step // cfg.eval_every > (step - batch_steps) // cfg.eval_every
        if periodic and cfg.eval_episodes and step < cfg.total_steps:
            scores = evaluate_into(last, cfg, self.out / "evals" / f"step_{step}", self.writer, step)
            if scores.get("S_bench", -np.inf) > self.best_score:  # selection on held-out seeds
                self.best_score = scores["S_bench"]
                metrics.update({f"eval/{k}": v for k, v in scores.items()})
                save(self.out / "best.pt")
                self.writer.add_scalar("eval/best_S_bench", self.best_score, step)

    def interrupted(self, step: int, save: Save) -> None:
        path = save(self.out / "interrupted.pt")
        self.writer.flush()
        print(f"interrupted at {step} steps; checkpoint saved to {path}")

    def finish(self, step: int, metrics: dict, save: Save, start: float) -> Path:
        """``final.pt``, its evaluation (best.pt if it is the best), the summary; the final path."""
        final = save(self.out / "final.pt")
        if self.cfg.eval_episodes > 0:
            scores = evaluate_into(final, self.cfg, self.out / "eval", self.writer, step, progress=self.progress)
            metrics.update({f"eval/{k}": v for k, v in scores.items()})
            if scores.get("S_bench", -np.inf) > self.best_score:
                self.best_score = scores["S_bench"]
                save(self.out / "best.pt")
        self.writer.close()
        print(json.dumps(summary(step, time.perf_counter() - start, metrics), indent=2))
        return final


def summary(step: int, wall_s: float, metrics: dict) -> dict:
    """The printed end-of-run summary: SUMMARY_KEYS, then the final evaluation's eval/*."""

    def plain(value):
        return float(value) if value is not None and math.isfinite(value) else None

    out = {"steps": int(step), "wall_s": round(wall_s, 1)}
    out.update({k: plain(metrics.get(k)) for k in SCALAR_TAGS})
    out.update({k: plain(v) for k, v in metrics.items() if k.startswith("eval/")})
    return out


# ------------------------------------------------------------------ held-out evaluation
def evaluate_into(checkpoint: Path, cfg: TrainConfig, out: Path, writer, step: int, progress: bool = False) -> dict:
    """Run the task's benchmark suite on ``checkpoint`` with the held-out ``eval_seed`` (report
    under ``out``) and log its metrics and a few evaluation trajectory figures to TensorBoard.
    Training's random state is left as it was, so evaluating does not change the run."""
    # Loading the agents builds networks, which draws from torch's global generator: without
    # this, every evaluation would change the rest of the training run.
    numpy_state = np.random.get_state()
    with torch.random.fork_rng(devices=[]):
        try:
            return _evaluate(checkpoint, cfg, out, writer, step, progress)
        finally:
            np.random.set_state(numpy_state)


def _evaluate(checkpoint: Path, cfg: TrainConfig, out: Path, writer, step: int, progress: bool) -> dict:
    from PIL import Image

    from smarts.benchmark.jobs import plan_jobs
    from smarts.benchmark.report import ReportAhead, write_report
    from smarts.benchmark.runner import run_jobs
    from smarts.benchmark.suites import load_suite

    suite = load_suite(cfg.eval_suite or TASK_SUITE[cfg.task])
    frozen = out / "policy.pt"  # the runner reads the file later: keep this step's weights
    out.mkdir(parents=True, exist_ok=True)
    frozen.write_bytes(Path(checkpoint).read_bytes())
    # The reference agents' episodes (same seeds every time) are run once per training run and reused.
    cache = out.parent / "reference_cache" if out.parent.name == "evals" else out.parent / "evals" / "reference_cache"
    jobs = plan_jobs([str(frozen)], suite, cfg.eval_episodes, out, seed=cfg.eval_seed, reference_cache=cache)
    ahead = ReportAhead(out, suite, [str(frozen)], jobs)  # logs read while the workers run the other episodes
    results = run_jobs(jobs, workers=cfg.eval_workers, progress=progress, on_result=ahead.offer)
    write_report(out, suite, [str(frozen)], results, ahead=ahead)
    scores = json.loads((out / "results.json").read_text())["agents"][str(frozen)]["scores"]
    overall = scores["overall"] if scores else {}
    for name, value in overall.items():
        if isinstance(value, (int, float)):
            writer.add_scalar(f"eval/{name}", value, step)
    for figure in sorted((out / "plots").glob("trajectories_*.png"))[:3]:
        image = np.asarray(Image.open(figure).convert("RGB"))
        writer.add_image(f"eval_trajectories/{figure.stem[len('trajectories_') :]}", image, step, dataformats="HWC")
    # A follow-camera video (HUD, legend) of the config's eval_video_scenario, else an informative
    # scenario (a junction, a merge or an exit), at its first held-out seed, played by TensorBoard's
    # Images tab.
    from train.enjoy import episode_frames, video_scenario, write_tensorboard_video

    name = video_scenario(suite, cfg.eval_video_scenario)
    entry = next(e for e in suite.scenarios if e.name == name)
    steps = int(round(entry.time_limit / entry.spec.step_length))
    frames = episode_frames(str(frozen), f"{cfg.eval_suite or TASK_SUITE[cfg.task]}:{entry.name}", seed=cfg.eval_seed,
                            max_steps=steps)  # fmt: skip
    write_tensorboard_video(writer, f"eval_video/{entry.name}", frames, step)
    return {k: v for k, v in overall.items() if isinstance(v, (int, float))}
