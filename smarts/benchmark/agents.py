"""Which agent a locator names, and how its policy drives: checked before any episode runs.

Agents are locators (``zoo:keep-lane``, a checkpoint path, a training run folder) that a policy
resolver turns into policies (``smarts.core.policies``): the installed default (the zoo), or the
``policy_resolver=`` given to the planner and the runner alike. A policy may declare its action
space, controller, interface, lane-relative and V2V settings as plain data; they are validated
here, with errors naming the agent, its file and the field, so a policy whose action space a suite
does not host is an error before any episode runs (:func:`check_agents`), never a silent
conversion. Reference agents (:data:`REFERENCE_AGENTS`) are benchmarked beside the requested ones
with the same suite, seeds and episode count, so every report has its floor and its simple
baseline. Kept apart from jobs and the episode loop so reports and training name agents without
loading the runner.
"""

from __future__ import annotations

import contextlib
import dataclasses
import hashlib
import os
import re
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from smarts.benchmark.suites import Suite
from smarts.comms.config import CommsConfig
from smarts.core.errors import AgentSetupError
from smarts.core.policies import Policy, PolicyResolver, resolve_policy
from smarts.core.spec import replace
from smarts.dynamics.lane_relative import LaneRelativeParams
from smarts.scenario import ACTION_SPACES, CONTROLLERS, LANE_RELATIVE_SPACES, ScenarioSpec
from smarts.sensors.interface import AgentInterface, interface_from_dict, interface_to_dict

REFERENCE_AGENTS = ("zoo:keep-lane", "zoo:random", "zoo:stand-still")
"""Benchmarked with every suite run unless asked not to: a simple baseline, chance, doing nothing."""


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
    return setups_and_digests(agents, suite, policy_resolver)[0]


def setups_and_digests(
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
    digest = file_digest(str(source)) if isinstance(source, (str, os.PathLike)) else b""
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


def file_digest(path: str) -> bytes:
    """The content hash of a file, or nothing for a locator that is not one."""
    try:
        return hashlib.sha256(Path(path).read_bytes()).digest() if Path(path).is_file() else b""
    except (OSError, ValueError):
        return b""
