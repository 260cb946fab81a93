"""Reading a scenario: YAML or a plain mapping validated into the spec models (``smarts.core.spec``),
which hold every field's type, range and cross-field check; this module adds what only a reader
knows: the file (its name is the scenario's default name, its folder resolves relative map paths),
the built-in maps' names, and whether a map file exists. Every problem is reported at once, one line
each: ``file: agents[1].mission.goal.radius: what was expected``, with a did-you-mean for a misspelt
key.
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any

import yaml

from smarts.core.errors import ScenarioError
from smarts.core.schema import validate
from smarts.core.spec.replay import REPLAY_MAP
from smarts.core.spec.scenario import BUILTIN_MAPS_CONTEXT, BUILTIN_PREFIX, ScenarioSpec
from smarts.scenario.builtin_maps import BUILTIN_MAPS, builtin_map_path


def read_scenario(data: Any, source: str = "<dict>", base_dir: str | os.PathLike | None = None) -> ScenarioSpec:
    """Validate a plain mapping (as loaded from YAML) into a spec.

    ``source`` prefixes error messages; a relative map path is resolved against ``base_dir``
    (the current directory when None).
    """
    folder = None if base_dir is None else Path(base_dir)
    spec = validate(ScenarioSpec, data, source, ScenarioError, {BUILTIN_MAPS_CONTEXT: list(BUILTIN_MAPS)})
    if not spec.map.startswith(BUILTIN_PREFIX) and spec.map != REPLAY_MAP:
        path = resolve_map_file(spec.map, folder)
        if not path.is_file():
            raise ScenarioError(f"{source}: map: map file {str(path)!r} does not exist")
    return spec.located(source, folder)


def read_scenario_file(path: str | os.PathLike) -> ScenarioSpec:
    """Read and validate a scenario YAML file; its name defaults to the file's name."""
    path = Path(path)
    source = str(path)
    try:
        text = path.read_text(encoding="utf-8")
    except OSError as exc:
        raise ScenarioError(f"{source}: cannot read scenario file: {exc.strerror or exc}") from None
    except UnicodeDecodeError as exc:
        raise ScenarioError(
            f"{source}: not a YAML text file (not UTF-8: byte {exc.object[exc.start]:#04x} at offset {exc.start})"
        ) from None
    try:
        data = yaml.safe_load(text)
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        where = f" at line {mark.line + 1}, column {mark.column + 1}" if mark else ""
        problem = getattr(exc, "problem", None) or str(exc)
        raise ScenarioError(f"{source}: invalid YAML{where}: {problem}") from None
    if data is None:  # an empty file: report its missing fields, not a missing name
        data = {}
    if isinstance(data, dict) and "name" not in data:
        data = {"name": path.name.split(".")[0], **data}
    return read_scenario(data, source, path.parent)


def resolve_map_file(map_value: str, base_dir: Path | None) -> Path:
    """A map file named by a scenario: relative paths are resolved against ``base_dir`` (the
    scenario file's folder; the current directory when None)."""
    path = Path(map_value).expanduser()
    if not path.is_absolute():
        path = (base_dir if base_dir is not None else Path.cwd()) / path
    return path


def map_path(spec: ScenarioSpec, cache_dir: str | os.PathLike | None = None) -> Path:
    """The map file to load for ``spec``: a built-in map is compiled (and cached) by netconvert
    first; a replay's own map is its recording."""
    if spec.builtin_map is not None:
        return builtin_map_path(spec.builtin_map, cache_dir)
    if spec.map == REPLAY_MAP and spec.replay is not None:
        from smarts.replay.load import replay_path

        return replay_path(spec.replay, spec.base_dir)
    return resolve_map_file(spec.map, spec.base_dir)
