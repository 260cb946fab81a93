"""The built-in scenario library: YAML files shipped in ``smarts/scenario/library/``."""

from __future__ import annotations

import os
from pathlib import Path

from smarts.core.errors import ScenarioError
from smarts.core.spec.scenario import ScenarioSpec
from smarts.scenario.reader import read_scenario_file

LIBRARY_DIR = Path(__file__).resolve().parent / "library"


def list_scenarios() -> list[str]:
    """Names of the built-in scenarios, sorted."""
    return sorted(p.name[: -len(".yaml")] for p in LIBRARY_DIR.glob("*.yaml"))


def scenario_path(name: str) -> Path:
    """The YAML file of a built-in scenario."""
    path = LIBRARY_DIR / f"{name}.yaml"
    if not name or "/" in name or os.sep in name or not path.is_file():
        raise ScenarioError(
            f"unknown scenario {name!r}; built-in scenarios: {', '.join(list_scenarios())} "
            "(or give a path to a .yaml file)"
        )
    return path


def load_scenario(name_or_path: str | os.PathLike) -> ScenarioSpec:
    """Load a built-in scenario by name, or any scenario file by path."""
    text = os.fspath(name_or_path)
    looks_like_path = (
        isinstance(name_or_path, Path) or text.endswith((".yaml", ".yml")) or "/" in text or os.sep in text
    )
    if looks_like_path:
        return read_scenario_file(text)
    return read_scenario_file(scenario_path(text))
