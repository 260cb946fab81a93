"""Training configuration: a schema (``smarts.core.schema``) read from YAML, overridden by CLI flags.

``configs/train/<task>.yaml`` holds the defaults of a task; ``--config FILE`` replaces them (a run's
``config.json`` too), and every top-level field can be overridden on the command line as
``--field-name value``. Command-line values are YAML: ``--total-steps 20000``, ``--hidden 256,256``
or ``--hidden [256,256]``, ``--reward "{follow: 2}"``, ``--eval-suite null``. The file and the
overrides are validated together by one model, and every problem is reported at once, each naming
the file (or the ``--flag``) and the dotted field, with a did-you-mean for a misspelt key.
"""

from __future__ import annotations

import dataclasses
import re
import types
import typing
from pathlib import Path
from typing import Annotated, Any, Callable, Literal

import yaml
from pydantic import (
    AfterValidator,
    BaseModel,
    Field,
    TypeAdapter,
    ValidationError,
    ValidationInfo,
    create_model,
    field_validator,
    model_serializer,
    model_validator,
)

from smarts.core.errors import ConfigError
from smarts.core.resources import config_path
from smarts.core.schema import Schema, describe, load_yaml
from smarts.core.spec import CONTROLLERS
from smarts.core.spec.lane_relative import LaneRelativeParams
from smarts.env.reward_weights import RewardWeights

CONFIG_DIR = config_path("train")
"""The shipped task configs (``configs/train/``, installed as ``smarts.configs``)."""
Task = Literal["platoon", "drive"]
TASKS = typing.get_args(Task)
TASK_SUITE = {"platoon": "adaptive", "drive": "collaborative"}
"""The benchmark suite of each task: its held-out evaluations' default."""
ACTION_SPACES = {"rtp": "relative_target_pose", "continuous": "continuous"}
"""The config's action-space names -> the simulator's."""
LIBS = ("torchrl", "sb3")
BACKENDS = ("per_env", "batched")
FLAGS = {"out": "--out-dir"}
"""Command-line flags whose name is not the field's (``--out`` is an alias of ``--out-dir``)."""


def flag(name: str) -> str:
    """The command-line flag of field ``name`` (``total_steps`` -> ``--total-steps``)."""
    return FLAGS.get(name, "--" + name.replace("_", "-"))


# ----------------------------------------------------------------------------- value rules
def _rule(test: Callable[[Any], bool], message: str) -> AfterValidator:
    def check(value: Any) -> Any:
        if not test(value):
            raise ValueError(message)
        return value

    return AfterValidator(check)


_Finite = Field(allow_inf_nan=False)
PositiveInt = Annotated[int, _rule(lambda v: v >= 1, "expected a positive integer")]
NonNegativeInt = Annotated[int, _rule(lambda v: v >= 0, "expected a non-negative number")]
Positive = Annotated[float, _Finite, _rule(lambda v: v > 0, "expected a positive number")]
NonNegative = Annotated[float, _Finite, _rule(lambda v: v >= 0, "expected a non-negative number")]
Fraction = Annotated[float, _rule(lambda v: 0 < v <= 1, "expected a number in (0, 1]")]


# ----------------------------------------------------------------------------- sections
class Section(Schema):
    """Settings that override some fields of a settings dataclass; the others keep its defaults.
    Dumped (config.json, checkpoints), a section holds only the fields it was given."""

    @model_serializer(mode="wrap")
    def _given(self, handler: Any) -> dict[str, Any]:
        data = handler(self)
        return {name: value for name, value in data.items() if name in self.model_fields_set}


def _section(settings: type, name: str, doc: str, kinds: dict[str, Any], default: Any) -> type[Section]:
    """A section model with the fields (and defaults) of the dataclass ``settings``."""
    fields = {
        f.name: kinds[f.name] if f.name in kinds else (default, Field(f.default)) for f in dataclasses.fields(settings)
    }
    return create_model(name, __base__=Section, __doc__=doc, __module__=__name__, **fields)


RewardSection = _section(
    RewardWeights,
    "RewardSection",
    "Task reward weights and limits (``smarts.env.reward_weights.RewardWeights`` fields).",
    {
        "task": (Task | None, Field(None, description="The task whose reward terms count; None: the config's task.")),
        **{
            name: (Positive, Field(getattr(RewardWeights, name)))
            for name in ("headway", "max_time_gap", "jerk_long_max", "jerk_lat_max", "accel_long_max", "accel_lat_max")
        },
    },  # fmt: skip
    NonNegative,
)
LaneRelativeSection = _section(
    LaneRelativeParams,
    "LaneRelativeSection",
    "How lane-relative commands drive (``smarts.dynamics.lane_relative.LaneRelativeParams`` fields).",
    {
        "threshold": (
            Annotated[float, _rule(lambda v: 0 < v < 1, "expected a number in (0, 1)")],
            Field(LaneRelativeParams.threshold),
        )
    },  # fmt: skip
    Positive,
)


# ----------------------------------------------------------------------------- the config
class TrainConfig(Schema):
    """A training run's settings (``configs/train/<task>.yaml``, recorded in its config.json)."""

    task: Task = Field(
        "platoon", description="platoon (follow a lead vehicle) | drive (turn at intersections, reach the exit)."
    )
    scenarios: list[str] = Field(
        default_factory=list,
        description="suite:scenario names (e.g. adaptive:a01_straight_free), suite:* for every scenario of a suite, "
        "or library scenario names.",
    )
    suite: str | None = Field(
        None,
        description="A benchmark suite (a name or a YAML path, e.g. one written by `smarts replay suite`): train on "
        "every scenario of it (replacing scenarios) and evaluate on it unless eval_suite is given.",
    )
    action_space: Literal[tuple(ACTION_SPACES)] = Field(
        "rtp", description="rtp (RelativeTargetPose) | continuous (throttle, brake, steering on the pybullet car)."
    )
    controller: Literal[CONTROLLERS] = Field(
        "lane_relative",
        description="lane_relative: the policy outputs (target speed, lane change) commands that the env turns into "
        "the action space's actions (smarts.dynamics.lane_relative); direct: raw actions.",
    )
    lane_relative: LaneRelativeSection = Field(
        default_factory=LaneRelativeSection,
        description="How lane-relative commands drive (smarts.dynamics.lane_relative.LaneRelativeParams fields, e.g. "
        "{max_jerk: 2.0}); recorded in checkpoints so evaluation drives the same.",
    )
    interface: dict[str, Any] = Field(
        default_factory=dict,
        description="The observation interface (smarts.sensors.interface fields, e.g. {lead: true}).",
    )
    reward: RewardSection = Field(
        default_factory=RewardSection,
        description="Task reward weights (smarts.env.reward_weights.RewardWeights fields); task defaults to this "
        "config's task.",
    )
    lib: Literal[LIBS] = Field("torchrl", description="torchrl | sb3 (Stable-Baselines3's PPO).")
    backend: Literal[BACKENDS] = Field(
        "per_env",
        description="batched: every copy, whatever its map, in one simulation of the batched core per process (this "
        "one with workers 0, else spread over the workers; a SUMO copy in a worker process of its own, as libsumo "
        "holds one simulation per process) | per_env: the same (kept for configs that name it: an episode gives the "
        "same bits whatever it is stepped beside, so one simulation per copy would only be slower). With ray_address "
        "each collector steps its share the same way.",
    )
    device: str = Field(
        "cpu",
        description="Where the learner runs, policy inference during collection and the PPO updates (lib torchrl; "
        "lib sb3: SB3's device): cpu | cuda, cuda:N: that GPU, the simulations staying on CPU workers (refused when "
        "torch sees none) | torch-cpu: the GPU's code path (explicit transfers) on the CPU, for tests. Before, this "
        "field placed the simulation's torch stages: that is sim_device now.",
    )
    sim_device: str = Field(
        "cpu",
        description="Where the simulation stages that have a torch version run: cpu: the compiled numpy kernels | "
        "torch-cpu: the torch stages on the CPU (to check them) | cuda, cuda:N: the torch stages on that GPU.",
    )
    total_steps: PositiveInt = Field(
        60_000,
        description="Env steps to train for, summed over the slots; the last batch takes only what is still "
        "needed, so a run ends less than one step of every slot past it (with ray_address: whole batches).",
    )
    envs: PositiveInt = Field(
        16, description="Scenario copies stepped together (in this process, or split over workers)."
    )
    workers: NonNegativeInt = Field(
        1,
        description="Processes that step the envs (<= envs): 0 steps them in this process, N >= 1 in N worker "
        "processes, each one simulation of its share, writing into one shared-memory buffer this process reads "
        "(SUMO copies always get a process of their own); with 2 or more, the policy acts for one half of the "
        "workers' copies while the other half steps (lib torchrl); with ray_address, the Ray collectors (>= 1).",
    )
    overlap: bool = Field(
        True,
        description="Collect the next batch while the learner updates on this one (lib torchrl): collection acts with "
        "the policy of one update before, which PPO's probability ratio accounts for; the two then share the cores "
        "instead of taking turns. false: collect with the policy just updated, then update, in turn.",
    )
    seed: NonNegativeInt = Field(0, description="Seed of torch, numpy and the training episodes.")
    frames_per_batch: PositiveInt = Field(2048, description="Env steps collected for each PPO update.")
    minibatch_size: PositiveInt = Field(256, description="Samples per gradient step (<= frames_per_batch).")
    epochs: PositiveInt = Field(4, description="Passes over each batch.")
    lr: Positive = Field(3e-4, description="Adam's learning rate (> 0).")
    gamma: Fraction = Field(0.99, description="Discount, in (0, 1].")
    gae_lambda: Fraction = Field(0.95, description="GAE's lambda, in (0, 1].")
    clip_epsilon: Positive = Field(0.2, description="PPO's ratio clip (> 0).")
    entropy_coeff: NonNegative = Field(0.001, description="Weight of the entropy bonus.")
    critic_coeff: NonNegative = Field(0.5, description="Weight of the value loss.")
    max_grad_norm: Positive = Field(0.5, description="Gradients are clipped to this norm (> 0).")
    target_kl: NonNegative = Field(
        0.05,
        description="Stop a batch's remaining epochs once the approximate KL to the collecting policy exceeds this "
        "(0: never).",
    )
    action_bound_coeff: NonNegative = Field(
        1.0,
        description="Weight of the loss on the Gaussian's mean outside the action box (train.ppo.action_bound_loss).",
    )
    hidden: list[int] = Field(default_factory=lambda: [128, 128], description="Hidden layer sizes of actor and critic.")
    init_log_std: list[float] = Field(
        default_factory=lambda: [-0.5],
        description="Initial log standard deviation of the Gaussian policy, in [-5, 1]: one value for every action "
        "component, or one per component (for lane-relative commands: speed, lane change).",
    )
    comms: dict[str, Any] | None = Field(
        None,
        description="V2V messaging for every training scenario, as a scenario's comms section (smarts.comms.config; "
        "e.g. {range: 50, latency: 1, penetration: 0.5}): agents then also observe messages and send a message "
        "part with each action; recorded in the checkpoint so evaluation runs with it. null: each scenario's own.",
    )
    obs_norm: bool = Field(True, description="Normalise observations by running statistics (kept in the checkpoint).")
    reward_scaling: bool = Field(
        True, description="Divide rewards by the running standard deviation of the discounted return."
    )
    obs_clip: Positive = Field(5.0, description="Normalised inputs are clipped to +-obs_clip.")
    obs_std_floor: Positive = Field(0.1, description="No feature is divided by less than this.")
    eval_every: NonNegativeInt = Field(
        0,
        description="Env steps between benchmark evaluations on held-out seeds (0: only at the end); best.pt is the "
        "checkpoint with the highest S_bench among them.",
    )
    eval_episodes: NonNegativeInt = Field(
        1, description="Episodes per scenario of each benchmark evaluation (0: none)."
    )
    eval_suite: str | None = Field(
        None,
        description="The benchmark suite of the evaluations (a name or a YAML path); null: the task's own (adaptive "
        "for platoon, collaborative for drive).",
    )
    eval_video_scenario: str | None = Field(
        None,
        description="The evaluation suite's scenario whose follow-camera video every held-out evaluation writes to "
        "TensorBoard; null: the suite's first with a junction, a merge or an exit.",
    )
    eval_workers: PositiveInt = Field(
        2,
        description="Processes that run each evaluation's episodes; 1 runs them in the training process (no start-up "
        "cost, for small suites; not with SUMO traffic while training SUMO in this process).",
    )
    eval_seed: NonNegativeInt = Field(
        3000,
        description="First seed of the evaluations; training episodes use seeds from 100000 up, and the suites' own "
        "benchmark seeds (1000, 2000) are neither, so selection and the final score are held out.",
    )
    torch_threads: PositiveInt = Field(
        1, description="torch threads per process (one is fastest for these small networks on a loaded machine)."
    )
    init_from: str | None = Field(
        None,
        description="Start from the networks and observation statistics of this checkpoint (a new run: fresh "
        "optimiser, step 0), e.g. a platoon policy fine-tuned on the pybullet car; unlike --resume the action space "
        "may differ, the observation and the commands' meaning may not.",
    )
    runs_dir: str = Field(
        "runs/train",
        description="Where runs go when out is not given: each run gets the next numbered folder under it "
        "(001, 002, ...) and runs_dir/latest points to the newest.",
    )
    out: str | None = Field(
        None,
        description="This run's exact folder (config.json, checkpoints, TensorBoard); one that holds another run is "
        "refused. null: a new numbered folder under runs_dir (or, with --resume, the checkpoint's own folder).",
    )
    ray_address: str | None = Field(
        None,
        description="Run the collectors as Ray actors: auto | local | HOST:PORT (needs the ray extra); null: no Ray.",
    )

    # ------------------------------------------------------------------ cross-field and nested checks
    @field_validator("scenarios")
    @classmethod
    def _some_scenarios(cls, names: list[str]) -> list[str]:
        if not names or not all(names):
            raise ValueError("expected at least one training scenario")
        return names

    @field_validator("comms")
    @classmethod
    def _comms(cls, data: dict[str, Any] | None) -> dict[str, Any] | None:
        from smarts.comms.config import CommsConfig

        if data is not None:
            try:
                CommsConfig.from_dict(data, "comms")
            except ValueError as err:
                raise ValueError(str(err).replace("comms.", "", 1)) from None
        return data

    @field_validator("hidden")
    @classmethod
    def _layers(cls, sizes: list[int]) -> list[int]:
        if not sizes or any(h < 1 for h in sizes):
            raise ValueError("expected a list of positive layer sizes")
        return sizes

    @field_validator("init_log_std")
    @classmethod
    def _log_std(cls, values: list[float]) -> list[float]:
        if not values or not all(-5.0 <= v <= 1.0 for v in values):
            raise ValueError("expected one or more numbers in [-5, 1]")
        return values

    @field_validator("workers")
    @classmethod
    def _workers_within_envs(cls, workers: int, info: ValidationInfo) -> int:
        envs = info.data.get("envs")
        if envs is not None and workers > envs:
            raise ValueError(f"must be <= envs ({envs})")
        return workers

    @field_validator("minibatch_size")
    @classmethod
    def _minibatch_within_batch(cls, size: int, info: ValidationInfo) -> int:
        frames = info.data.get("frames_per_batch")
        if frames is not None and size > frames:
            raise ValueError(f"must be <= frames_per_batch ({frames})")
        return size

    @field_validator("device", "sim_device")
    @classmethod
    def _device_name(cls, name: str) -> str:
        from smarts.dynamics.pose_control_torch import check_device_name  # torch: not for --help

        check_device_name(name)  # whether the GPU is there is asked when the envs are built
        return name

    @model_validator(mode="after")
    def _whole_suite(self) -> "TrainConfig":
        if self.suite:
            object.__setattr__(self, "scenarios", [f"{self.suite}:*"])
            if self.eval_suite is None:
                object.__setattr__(self, "eval_suite", self.suite)
        return self

    @model_validator(mode="after")
    def _video_scenario(self) -> "TrainConfig":
        if self.eval_video_scenario is not None:
            from smarts.benchmark.suites import load_suite

            suite = load_suite(self.eval_suite or TASK_SUITE[self.task])
            names = [s.name for s in suite.scenarios]
            if self.eval_video_scenario not in names:
                raise ValueError(
                    f"eval_video_scenario: suite {suite.name!r} has no scenario {self.eval_video_scenario!r}; "
                    f"it has {', '.join(names)}"
                )
        return self

    @model_validator(mode="after")
    def _ray_workers(self) -> "TrainConfig":
        if self.ray_address and self.workers < 1:
            raise ValueError("workers: with ray_address, the number of Ray collectors (>= 1), got 0")
        return self

    @field_validator("interface")
    @classmethod
    def _interface(cls, data: dict[str, Any]) -> dict[str, Any]:
        from smarts.sensors.interface import interface_from_dict

        try:
            interface_from_dict(data)
        except ValueError as err:  # InterfaceError names the dotted field: keep the part below interface
            path, problem = getattr(err, "path", ""), getattr(err, "problem", str(err))
            raise ValueError(
                f"{path[len('interface.') :]}: {problem}" if path.startswith("interface.") else problem
            ) from None
        return data

    @field_validator("reward", "lane_relative")
    @classmethod
    def _settings(cls, section: Section, info: ValidationInfo) -> Section:
        try:  # the dataclass's own checks (the section's rules already hold them)
            if info.field_name == "reward":
                RewardWeights(**_reward_settings(section, info.data.get("task", "platoon")))
            else:
                LaneRelativeParams(**section.model_dump())
        except (TypeError, ValueError) as err:
            raise ValueError(str(err)) from None
        return section

    # ------------------------------------------------------------------ what the trainers build from it
    def observation_interface(self):
        """The ``AgentInterface`` of ``interface``."""
        from smarts.sensors.interface import interface_from_dict

        return interface_from_dict(self.interface)

    def comms_config(self):
        """The ``CommsConfig`` of ``comms`` (None: each scenario keeps its own)."""
        from smarts.comms.config import CommsConfig

        return None if self.comms is None else CommsConfig.from_dict(self.comms, "comms")

    def lane_relative_params(self) -> LaneRelativeParams:
        """The ``LaneRelativeParams`` of ``lane_relative``."""
        return LaneRelativeParams(**self.lane_relative.model_dump())

    def reward_weights(self) -> RewardWeights:
        """The ``RewardWeights`` of ``reward`` (the task's reward unless ``reward.task`` says)."""
        return RewardWeights(**_reward_settings(self.reward, self.task))


def _reward_settings(section: Section, task: str) -> dict[str, Any]:
    settings = section.model_dump()
    if settings.get("task") is None:
        settings["task"] = task
    return settings


# ----------------------------------------------------------------------------- command-line values
def _is_text(annotation: Any) -> bool:
    """Whether a field holds text (str, a Literal of names, optional text): kept as written."""
    if annotation is str:
        return True
    args = typing.get_args(annotation)
    if typing.get_origin(annotation) is Literal:
        return all(isinstance(a, str) for a in args)
    if typing.get_origin(annotation) in (typing.Union, types.UnionType):
        return all(a is type(None) or _is_text(a) for a in args)
    return False


def _is_mapping(annotation: Any) -> bool:
    """Whether a field holds a mapping (a dict, a section model, or an optional one)."""
    if typing.get_origin(annotation) in (typing.Union, types.UnionType):
        return any(_is_mapping(a) for a in typing.get_args(annotation) if a is not type(None))
    return typing.get_origin(annotation) is dict or (isinstance(annotation, type) and issubclass(annotation, BaseModel))


def _yaml(text: str) -> Any:
    try:
        return yaml.safe_load(text)
    except yaml.YAMLError:
        return text  # the model then says what was expected


def from_command_line(name: str, text: str) -> Any:
    """The command-line string ``text`` of field ``name`` parsed into the field's type where it can
    be (lax: ``"256"`` -> 256, ``"yes"`` -> true, ``"256,256"`` or ``"[256, 256]"`` -> [256, 256],
    ``"{follow: 2}"`` -> a mapping, ``null`` -> None); what cannot be parsed is passed on as
    written for the model to reject with the field's own message."""
    info = TrainConfig.model_fields.get(name)
    if info is None:
        return text
    kind = info.annotation
    if _is_text(kind):
        optional = type(None) in typing.get_args(kind)
        return None if optional and text.strip() in ("", "null", "~", "None") else text
    if typing.get_origin(kind) is list:
        stripped = text.strip()
        value = _yaml(stripped) if stripped.startswith("[") else [v for v in re.split(r"[,\s]+", stripped) if v]
        if _is_text(typing.get_args(kind)[0]) or not isinstance(value, list):
            return value
    elif _is_mapping(kind):
        value = _yaml(text)
        if value is None:
            return None if type(None) in typing.get_args(kind) else {}
        return value
    else:
        value = text
    try:
        return TypeAdapter(kind).validate_python(value, strict=False)
    except ValidationError:
        return value


# ----------------------------------------------------------------------------- loading
def config_file(path: str | Path) -> Path:
    """``--config``'s file: ``path`` itself, or for a bare name that is no file here (``platoon-two-cores``)
    the shipped ``configs/train/<name>.yaml``, so a shipped recipe is named the same way in a
    checkout and from a wheel."""
    path = Path(path)
    if path.exists() or path.name != str(path) or path.suffix:
        return path
    if (CONFIG_DIR / f"{path}.yaml").is_file():
        return CONFIG_DIR / f"{path}.yaml"
    shipped = ", ".join(sorted(p.stem for p in CONFIG_DIR.glob("*.yaml")))
    raise ConfigError(f"--config {path}: no such file, and no shipped training config of that name ({shipped})")


def load_config(task: str | None = None, path: str | Path | None = None, overrides: dict | None = None) -> TrainConfig:
    """Defaults of ``task`` (or the file ``path``: a config YAML or a run's config.json), then
    ``overrides`` (field -> value; strings are parsed as on the command line), validated together.
    Every problem is reported at once, named by the file or the override's ``--flag``."""
    if path is None:
        if task not in TASKS:
            raise ConfigError(f"unknown task {task!r}; expected one of {', '.join(TASKS)}")
        path = CONFIG_DIR / f"{task}.yaml"
    path = config_file(path)
    source = str(path)
    data = load_yaml(path, "training config", ConfigError)
    if data is None:
        data = {}
    if not isinstance(data, dict):
        raise ConfigError(f"{source}: expected a mapping of training settings, got {type(data).__name__}")
    values, origin = dict(data), {}
    if task is not None:
        values.setdefault("task", task)
    for name, value in (overrides or {}).items():
        known = TrainConfig.model_fields.get(name)
        if value is None and known is not None and known.default is not None:
            continue  # not given
        values[name] = from_command_line(name, value) if isinstance(value, str) else value
        origin[name] = flag(name)
    try:
        return TrainConfig.model_validate(values)
    except ValidationError as exc:
        lines = [
            describe(TrainConfig, p, origin.get(p["loc"][0], source) if p["loc"] else source) for p in exc.errors()
        ]
        raise ConfigError("\n".join(lines)) from None


def task_defaults(task: str | None, path: str | Path | None = None) -> tuple[dict[str, Any], str]:
    """The raw settings of the task's YAML (or ``path``) and the file's name, for ``--help``; an
    unreadable file gives no settings (the error comes when the config is loaded)."""
    if path is None:
        if task not in TASKS:
            return {}, ""
        path = CONFIG_DIR / f"{task}.yaml"
    try:
        path = config_file(path)
        data = load_yaml(path, "training config", ConfigError)
    except ConfigError:
        return {}, ""
    return (data, Path(path).name) if isinstance(data, dict) else ({}, "")
