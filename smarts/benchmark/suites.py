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

import dataclasses
import math
from dataclasses import dataclass, field
from pathlib import Path

import yaml

from smarts.scenario import ScenarioError, ScenarioSpec
from smarts.scenario.spec import ACTION_SPACES

SUITES_DIR = Path(__file__).resolve().parents[2] / "configs" / "benchmark"
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


def load_suite(name_or_path: str | Path) -> Suite:
    """A suite by name (``collaborative``, ``adaptive``) or from a YAML file."""
    path = Path(name_or_path)
    if not path.suffix:
        path = SUITES_DIR / f"{name_or_path}.yaml"
        if not path.is_file():
            raise ValueError(f"unknown benchmark suite {str(name_or_path)!r}; known: {', '.join(suite_names())}")
    source = str(path)
    try:
        data = yaml.safe_load(path.read_text())
    except OSError as err:
        raise ScenarioError(f"{source}: cannot read suite file: {err.strerror or err}") from None
    except yaml.YAMLError as err:
        raise ScenarioError(f"{source}: invalid YAML: {err}") from None
    return _read_suite(data, source)


def _read_suite(data, source: str) -> Suite:
    def fail(where: str, message: str) -> ScenarioError:
        return ScenarioError(f"{source}: {where}: {message}")

    if not isinstance(data, dict):
        raise ScenarioError(f"{source}: expected a mapping with name, task and scenarios")
    allowed = {"name", "task", "episodes", "seed", "scenarios", "vehicle_types", "action_spaces"}
    for key in data:
        if key not in allowed:
            raise fail(str(key), f"unknown field; allowed: {', '.join(sorted(allowed))}")
    task = data.get("task")
    if task not in TASKS:
        raise fail("task", f"expected one of {', '.join(TASKS)}, got {task!r}")
    episodes = data.get("episodes", 3)
    if not isinstance(episodes, int) or isinstance(episodes, bool) or episodes < 1:
        raise fail("episodes", f"expected a positive integer, got {episodes!r}")
    seed = data.get("seed", 0)
    if not isinstance(seed, int) or isinstance(seed, bool) or seed < 0:
        raise fail("seed", f"expected a non-negative integer, got {seed!r}")
    spaces = data.get("action_spaces", list(DEFAULT_ACTION_SPACES))
    if (
        not isinstance(spaces, list)
        or not spaces
        or any(sp not in ACTION_SPACES for sp in spaces)
        or len(set(spaces)) != len(spaces)
    ):
        raise fail("action_spaces", f"expected a non-empty list of distinct names from {', '.join(ACTION_SPACES)}, got {spaces!r}")
    items = data.get("scenarios")
    if not isinstance(items, list) or not items:
        raise fail("scenarios", "expected a non-empty list")
    scenarios: list[SuiteScenario] = []
    for i, item in enumerate(items):
        where = f"scenarios[{i}]"
        if not isinstance(item, dict):
            raise fail(where, "expected a mapping")
        for key in item:
            if key not in {"name", "difficulty", "time_limit", "scenario", "follow"}:
                raise fail(f"{where}.{key}", "unknown field; allowed: name, difficulty, time_limit, scenario, follow")
        name = item.get("name")
        if not isinstance(name, str) or not name:
            raise fail(f"{where}.name", f"expected a non-empty string, got {name!r}")
        if any(s.name == name for s in scenarios):
            raise fail(f"{where}.name", f"duplicate scenario name {name!r}")
        difficulty = item.get("difficulty")
        if difficulty not in DIFFICULTIES:
            raise fail(f"{where}.difficulty", f"expected one of {', '.join(DIFFICULTIES)}, got {difficulty!r}")
        limit = item.get("time_limit")
        if isinstance(limit, bool) or not isinstance(limit, (int, float)) or not limit > 0:
            raise fail(f"{where}.time_limit", f"expected a positive number of seconds, got {limit!r}")
        body = item.get("scenario")
        if not isinstance(body, dict):
            raise fail(f"{where}.scenario", "expected an inline scenario spec (a mapping)")
        body = dict(body)
        dt = body.get("step_length", 0.1)
        body.setdefault("name", name)
        body.setdefault("episode_steps", int(math.ceil(float(limit) / float(dt) - 1e-9)))
        body.setdefault("events", {"terminate_on": TERMINATE_ON[task]})
        spec = ScenarioSpec.from_dict(body, source=f"{source}: {where}.scenario", base_dir=Path(source).parent)
        follow = item.get("follow") or {}
        if not isinstance(follow, dict):
            raise fail(f"{where}.follow", "expected a mapping of agent id -> lead vehicle id")
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
                dataclasses.replace(a, mission=dataclasses.replace(a.mission, follow=follow[a.id]))
                if a.id in follow else a
                for a in spec.agents
            ]  # fmt: skip
            spec = dataclasses.replace(spec, agents=agents)
        scenarios.append(SuiteScenario(name, difficulty, float(limit), spec, dict(follow)))
    return Suite(str(data.get("name", Path(source).stem)), task, episodes, seed, scenarios, source, tuple(spaces))
