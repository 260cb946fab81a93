"""The README's commands and examples are what CI and users run: keep them working."""

import re
from pathlib import Path

import yaml

from smarts.env.assembly import build_simulation
from smarts.scenario import ScenarioSpec

ROOT = Path(__file__).resolve().parents[1]
README = (ROOT / "README.md").read_text()


def _blocks(language: str) -> list[str]:
    return re.findall(rf"```{language}\n(.*?)```", README, flags=re.S)


def test_ci_runs_the_readme_test_command():
    test_command = next(b.strip() for b in _blocks("bash") if "pytest" in b)
    assert test_command in (ROOT / ".ci" / "run").read_text()


def test_intersection_example_drives_both_agents_to_their_goals(capsys):
    example = _blocks("python")[0]
    namespace: dict = {}
    exec(compile(example, "README example", "exec"), namespace)
    printed = capsys.readouterr().out.splitlines()
    assert printed == ["agent_0 ['reached_goal']", "agent_1 ['reached_goal']"]
    assert namespace["frame"].ndim == 3


def test_gymnasium_example_runs():
    namespace: dict = {}
    exec(compile(_blocks("python")[1], "README gym example", "exec"), namespace)
    obs, _ = namespace["env"].reset(seed=0)
    assert namespace["env"].observation_space.contains(obs)


def test_scenario_file_example_is_valid(tmp_path):
    text = _blocks("yaml")[0]
    spec = ScenarioSpec.from_dict(yaml.safe_load(text), source="README scenario")
    sim = build_simulation(spec)
    sim.reset()
    assert sim.agent_ids == ["agent_0"]
