"""Benchmark suites: named lists of scenarios with a task, difficulty and time limit each.

A suite file (``configs/benchmark/<name>.yaml``) holds ``name``, ``task`` (collaborative |
adaptive), ``episodes`` and ``seed`` defaults, and ``scenarios``: each with ``name``,
``difficulty`` (easy | medium | hard), ``time_limit`` (s), an inline ``scenario`` spec (the schema
of the scenario library) and, for adaptive tasks, ``follow`` (mission agent -> lead vehicle id).
An optional ``action_spaces`` lists the simulator action spaces the suite hosts (default: the
benchmark's three, ``relative_target_pose``, ``target_pose`` and ``continuous``; ``lane`` is a
different kinematic vehicle model and is hosted only where a suite says so). The runner drives
every learning agent of a scenario in the benchmarked policy's own action space and refuses a
policy whose space the suite does not host. Errors name the file and the field.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Annotated, Any, Literal

from pydantic import Field, field_validator

from smarts.core.errors import ScenarioError
from smarts.core.resources import config_path
from smarts.core.schema import Schema, load_yaml, validate
from smarts.core.spec import replace
from smarts.scenario import ACTION_SPACES, ScenarioSpec, read_scenario

SUITES_DIR = config_path("benchmark")
"""The shipped suites (``configs/benchmark/``, installed as ``smarts.configs``)."""
TASKS = ("collaborative", "adaptive")
DIFFICULTIES = ("easy", "medium", "hard")
TERMINATE_ON = {
    "collaborative": ["collision", "off_road", "reached_goal", "max_steps"],
    "adaptive": ["collision", "off_road", "max_steps"],
}
"""Events that end a mission vehicle's episode, by task (a scenario may set its own)."""
DEFAULT_ACTION_SPACES = ("relative_target_pose", "target_pose", "continuous")
"""The benchmark's action spaces, hosted by every suite that does not list its own."""


@dataclass
class SuiteScenario:
    name: str
    difficulty: str
    time_limit: float
    spec: ScenarioSpec
    follow: dict[str, str] = field(default_factory=dict)


@dataclass
class Suite:
    name: str
    task: str
    episodes: int
    seed: int
    scenarios: list[SuiteScenario]
    source: str = ""
    action_spaces: tuple[str, ...] = DEFAULT_ACTION_SPACES
    """Simulator action spaces a benchmarked policy may act in on this suite."""


def suite_names() -> list[str]:
    return sorted(p.stem for p in SUITES_DIR.glob("*.yaml") if p.stem != "metrics")


class SuiteScenarioFile(Schema):
    """One scenario entry of a suite file, as written (the inline spec is read by the scenario
    reader afterwards)."""

    name: Annotated[str, Field(min_length=1)]
    difficulty: Literal["easy", "medium", "hard"]
    time_limit: Annotated[float, Field(gt=0, allow_inf_nan=False, description="seconds")]
    scenario: dict[str, Any] = Field(description="an inline scenario spec")
    follow: dict[str, str] = Field(default_factory=dict, description="mission agent id -> lead vehicle id")


class SuiteFile(Schema):
    """A suite file's top level."""

    name: str | None = None
    task: Literal["collaborative", "adaptive"]
    episodes: Annotated[int, Field(ge=1)] = 3
    seed: Annotated[int, Field(ge=0)] = 0
    scenarios: Annotated[list[SuiteScenarioFile], Field(min_length=1)]
    vehicle_types: Any = Field(None, description="a place for YAML anchors the scenarios refer to")
    action_spaces: Annotated[list[str], Field(min_length=1)] = list(DEFAULT_ACTION_SPACES)

    @field_validator("action_spaces")
    @classmethod
    def _known_spaces(cls, spaces: list[str]) -> list[str]:
        if any(sp not in ACTION_SPACES for sp in spaces) or len(set(spaces)) != len(spaces):
            raise ValueError(f"expected distinct names from {', '.join(ACTION_SPACES)}")
        return spaces


def load_suite(name_or_path: str | Path) -> Suite:
    """A suite by name (``collaborative``, ``adaptive``) or from a YAML file."""
    path = Path(name_or_path)
    if not path.suffix:
        path = SUITES_DIR / f"{name_or_path}.yaml"
        if not path.is_file():
            raise ValueError(f"unknown benchmark suite {str(name_or_path)!r}; known: {', '.join(suite_names())}")
    return _read_suite(load_yaml(path, "suite file", ScenarioError), str(path))


def _read_suite(data, source: str) -> Suite:
    def fail(where: str, message: str) -> ScenarioError:
        return ScenarioError(f"{source}: {where}: {message}")

    suite = validate(SuiteFile, data, source, ScenarioError)
    task = suite.task
    scenarios: list[SuiteScenario] = []
    for i, item in enumerate(suite.scenarios):
        where = f"scenarios[{i}]"
        name, limit = item.name, item.time_limit
        if any(s.name == name for s in scenarios):
            raise fail(f"{where}.name", f"duplicate scenario name {name!r}")
        body = dict(item.scenario)
        dt = body.get("step_length", 0.1)
        body.setdefault("name", name)
        body.setdefault("episode_steps", int(math.ceil(float(limit) / float(dt) - 1e-9)))
        body.setdefault("events", {"terminate_on": TERMINATE_ON[task]})
        spec = read_scenario(body, source=f"{source}: {where}.scenario", base_dir=Path(source).parent)
        follow = item.follow
        trips = {t.id for t in (spec.traffic.trips if spec.traffic else [])}
        for agent_id, lead in follow.items():
            if agent_id not in spec.agent_ids:
                raise fail(f"{where}.follow.{agent_id}", f"no such agent; agents: {spec.agent_ids}")
            if lead not in trips:
                raise fail(f"{where}.follow.{agent_id}", f"lead {lead!r} is not a trip of the scenario's traffic")
        if task == "adaptive" and not follow:
            raise fail(f"{where}.follow", "adaptive scenarios need a lead vehicle to follow")
        if follow:  # the followers' missions name their lead (observations, rewards, SFD)
            agents = [
                replace(a, mission=replace(a.mission, follow=follow[a.id]))
                if a.id in follow else a
                for a in spec.agents
            ]  # fmt: skip
            spec = replace(spec, agents=agents)
        scenarios.append(SuiteScenario(name, item.difficulty, float(limit), spec, dict(follow)))
    name = suite.name or Path(source).stem
    return Suite(name, task, suite.episodes, suite.seed, scenarios, source, tuple(suite.action_spaces))
