"""Training configuration: a dataclass schema, read from YAML, overridden by CLI flags.

``configs/train/<task>.yaml`` holds the defaults of a task; ``--config FILE`` replaces them and
every field can be overridden as ``--field value`` (``--total-steps 20000``). Values are
validated once, with errors naming the file and the field.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field, fields
from pathlib import Path
from typing import Any

import yaml

CONFIG_DIR = Path(__file__).resolve().parents[1] / "configs" / "train"
TASKS = ("platoon", "drive")
ACTION_SPACES = {"rtp": "relative_target_pose", "continuous": "continuous"}
LIBS = ("torchrl", "sb3")
CONTROLLERS = ("direct", "lane_relative")


class ConfigError(ValueError):
    pass


@dataclass
class TrainConfig:
    task: str = "platoon"
    scenarios: list[str] = field(default_factory=list)
    """``suite:scenario`` names (e.g. ``adaptive:a01_straight_free``), ``suite:*`` for every
    scenario of a suite, or library scenario names."""
    action_space: str = "rtp"
    controller: str = "lane_relative"
    """``lane_relative``: the policy outputs (acceleration, lane change) commands that the env turns
    into the action space's actions (``smarts.dynamics.lane_relative``); ``direct``: raw actions."""
    lane_relative: dict = field(default_factory=dict)
    """How lane-relative commands drive (``smarts.dynamics.lane_relative.LaneRelativeParams``
    fields, e.g. ``{max_jerk: 2.0}``); recorded in checkpoints so evaluation drives the same."""
    interface: dict = field(default_factory=dict)
    """The observation interface (``smarts.sensors.interface`` fields, e.g. ``{lead: true}``)."""
    reward: dict = field(default_factory=dict)
    """Task reward weights (``smarts.env.task_rewards.RewardWeights`` fields); ``task`` defaults
    to this config's task."""
    lib: str = "torchrl"
    total_steps: int = 60_000
    envs: int = 16
    """Scenario copies stepped together (in this process, or split over ``workers``)."""
    workers: int = 1
    seed: int = 0
    frames_per_batch: int = 2048
    minibatch_size: int = 256
    epochs: int = 4
    lr: float = 3e-4
    gamma: float = 0.99
    gae_lambda: float = 0.95
    clip_epsilon: float = 0.2
    entropy_coeff: float = 0.001
    critic_coeff: float = 0.5
    max_grad_norm: float = 0.5
    target_kl: float = 0.05
    """Stop a batch's remaining epochs once the approximate KL to the collecting policy exceeds
    this (0: never)."""
    action_bound_coeff: float = 1.0
    """Weight of the loss on the Gaussian's mean outside the action box (``train.ppo.action_bound_loss``)."""
    hidden: list[int] = field(default_factory=lambda: [128, 128])
    init_log_std: list[float] = field(default_factory=lambda: [-0.5])
    """Initial log standard deviation of the Gaussian policy: one value for every action
    component, or one per component (for lane-relative commands: speed, lane change)."""
    obs_norm: bool = True
    """Normalise observations by running statistics (kept in the checkpoint)."""
    reward_scaling: bool = True
    """Divide rewards by the running standard deviation of the discounted return."""
    obs_clip: float = 5.0
    obs_std_floor: float = 0.1
    """Normalised inputs are clipped to +-obs_clip; no feature is divided by less than this."""
    eval_every: int = 0
    """Env steps between benchmark evaluations on held-out seeds (0: only at the end); best.pt is
    the checkpoint with the highest S_bench among them."""
    eval_episodes: int = 1
    """Episodes per scenario of each benchmark evaluation (0: none)."""
    eval_suite: str | None = None
    """The benchmark suite of the evaluations (a name or a YAML path); None: the task's own
    (``adaptive`` for platoon, ``collaborative`` for drive)."""
    eval_workers: int = 2
    """Processes that run each evaluation's episodes; 1 runs them in the training process (no
    start-up cost, for small suites; not with SUMO traffic while training SUMO in this process)."""
    eval_seed: int = 3000
    """First seed of the evaluations; training episodes use seeds from 100_000 up, and the suites'
    own benchmark seeds (1000, 2000) are neither, so selection and the final score are held out."""
    torch_threads: int = 1
    """torch threads per process (one is fastest for these small networks on a loaded machine)."""
    init_from: str | None = None
    """Start from the networks and observation statistics of this checkpoint (a new run: fresh
    optimiser, step 0), e.g. a platoon policy fine-tuned on the pybullet car; unlike ``--resume``
    the action space may differ, the observation and the commands' meaning may not."""
    out: str = "runs/train"
    ray_address: str | None = None

    def validate(self, source: str) -> "TrainConfig":
        def fail(name: str, message: str) -> ConfigError:
            return ConfigError(f"{source}: {name}: {message}")

        if self.task not in TASKS:
            raise fail("task", f"expected one of {', '.join(TASKS)}, got {self.task!r}")
        if self.action_space not in ACTION_SPACES:
            raise fail("action_space", f"expected one of {', '.join(ACTION_SPACES)}, got {self.action_space!r}")
        if self.controller not in CONTROLLERS:
            raise fail("controller", f"expected one of {', '.join(CONTROLLERS)}, got {self.controller!r}")
        try:
            self.observation_interface()
        except ValueError as err:
            raise fail("interface", str(err)) from None
        try:
            self.lane_relative_params()
        except (TypeError, ValueError) as err:
            raise fail("lane_relative", str(err)) from None
        try:
            self.reward_weights()
        except (TypeError, ValueError) as err:
            raise fail("reward", str(err)) from None
        if self.lib not in LIBS:
            raise fail("lib", f"expected one of {', '.join(LIBS)}, got {self.lib!r}")
        for name in ("total_steps", "envs", "workers", "frames_per_batch", "minibatch_size", "epochs", "eval_workers"):
            if getattr(self, name) < 1:
                raise fail(name, f"expected a positive integer, got {getattr(self, name)}")
        if self.workers > self.envs:
            raise fail("workers", f"must be <= envs ({self.envs})")
        if self.minibatch_size > self.frames_per_batch:
            raise fail("minibatch_size", f"must be <= frames_per_batch ({self.frames_per_batch})")
        for name in ("lr", "clip_epsilon", "max_grad_norm"):
            if not getattr(self, name) > 0:
                raise fail(name, f"expected a positive number, got {getattr(self, name)}")
        for name in ("gamma", "gae_lambda"):
            if not 0 < getattr(self, name) <= 1:
                raise fail(name, f"expected a number in (0, 1], got {getattr(self, name)}")
        for name in ("obs_clip", "obs_std_floor", "torch_threads"):
            if not getattr(self, name) > 0:
                raise fail(name, f"expected a positive number, got {getattr(self, name)}")
        for name in ("entropy_coeff", "critic_coeff", "action_bound_coeff", "target_kl", "eval_every", "eval_episodes", "seed", "eval_seed"):
            if getattr(self, name) < 0:
                raise fail(name, f"expected a non-negative number, got {getattr(self, name)}")
        if not self.init_log_std or not all(-5.0 <= v <= 1.0 for v in self.init_log_std):
            raise fail("init_log_std", f"expected one or more numbers in [-5, 1], got {self.init_log_std}")
        if not self.hidden or any(h < 1 for h in self.hidden):
            raise fail("hidden", f"expected a list of positive layer sizes, got {self.hidden}")
        if not self.scenarios:
            raise fail("scenarios", "expected at least one training scenario")
        return self

    def observation_interface(self):
        """The ``AgentInterface`` of ``interface``."""
        from smarts.sensors.interface import interface_from_dict

        return interface_from_dict(self.interface)

    def lane_relative_params(self):
        """The ``LaneRelativeParams`` of ``lane_relative``."""
        from smarts.dynamics.lane_relative import LaneRelativeParams

        known = {f.name for f in fields(LaneRelativeParams)}
        unknown = sorted(set(self.lane_relative) - known)
        if unknown:
            raise ValueError(f"unknown settings {unknown}; known: {', '.join(sorted(known))}")
        return LaneRelativeParams(**self.lane_relative)

    def reward_weights(self):
        """The ``RewardWeights`` of ``reward`` (the task's reward unless ``reward.task`` says)."""
        from smarts.env.task_rewards import RewardWeights

        known = {f.name for f in fields(RewardWeights)}
        unknown = sorted(set(self.reward) - known)
        if unknown:
            raise ValueError(f"unknown reward terms {unknown}; known: {', '.join(sorted(known))}")
        return RewardWeights(**{"task": self.task, **self.reward})


def _coerce(name: str, value: Any, kind: Any, source: str) -> Any:
    origin = getattr(kind, "__origin__", None)
    text = str(kind)
    try:
        if text == "bool":
            if isinstance(value, str) and value.lower() in ("true", "false", "yes", "no", "1", "0"):
                return value.lower() in ("true", "yes", "1")
            if not isinstance(value, bool):
                raise ConfigError(f"{source}: {name}: expected true or false, got {value!r}")
            return value
        if text == "dict":
            if isinstance(value, str):  # from the command line: a YAML/JSON mapping
                value = yaml.safe_load(value) or {}
            if not isinstance(value, dict):
                raise ConfigError(f"{source}: {name}: expected a mapping, got {value!r}")
            return value
        if isinstance(value, str) and ("int" in text and "list" not in text):
            return int(value)
        if isinstance(value, str) and text == "float":
            return float(value)
        if isinstance(value, str) and "list" in text:
            items = [v for v in value.replace(",", " ").split() if v]
            if "int" in text:
                return [int(v) for v in items]
            return [float(v) for v in items] if "float" in text else items
        if text == "float" and isinstance(value, int) and not isinstance(value, bool):
            return float(value)
    except (ValueError, yaml.YAMLError):
        raise ConfigError(f"{source}: {name}: expected {text}, got {value!r}") from None
    expected = {"int": int, "float": float, "str": str}.get(text)
    if expected is not None and (not isinstance(value, expected) or isinstance(value, bool)):
        raise ConfigError(f"{source}: {name}: expected {text}, got {value!r}")
    del origin
    return value


def load_config(task: str | None = None, path: str | Path | None = None, overrides: dict | None = None) -> TrainConfig:
    """Defaults of ``task`` (or ``path``), then ``overrides``; validated."""
    if path is None:
        if task not in TASKS:
            raise ConfigError(f"unknown task {task!r}; expected one of {', '.join(TASKS)}")
        path = CONFIG_DIR / f"{task}.yaml"
    path = Path(path)
    source = str(path)
    try:
        data = yaml.safe_load(path.read_text()) or {}
    except OSError as err:
        raise ConfigError(f"{source}: cannot read: {err.strerror or err}") from None
    except yaml.YAMLError as err:
        raise ConfigError(f"{source}: invalid YAML: {err}") from None
    if not isinstance(data, dict):
        raise ConfigError(f"{source}: expected a mapping of training settings")
    kinds = {f.name: f.type for f in fields(TrainConfig)}
    values = {}
    for name, value in {**data, **(overrides or {})}.items():
        if name not in kinds:
            raise ConfigError(f"{source}: {name}: unknown setting; known: {', '.join(kinds)}")
        if value is None and name not in ("ray_address", "eval_suite", "init_from"):
            continue
        origin = "command line" if overrides and name in overrides else source
        values[name] = _coerce(name, value, kinds[name], origin)
    if task is not None and "task" not in values:
        values["task"] = task
    return dataclasses.replace(TrainConfig(), **values).validate(source)
