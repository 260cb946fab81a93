"""Validating a scenario end to end, as ``smarts scenario validate`` does: read the file, build its
map (netconvert for built-in and OpenDRIVE maps), check every mission and traffic entry on it
(``smarts.scenario.map_check``), let the chosen traffic engine check its traffic as it would at
reset, and plan every agent's route as the simulation does. Every problem is collected as one line
naming the file and field; bad input of any kind (unreadable or invalid YAML, a missing map file,
a map netconvert rejects) is a problem, never an exception.
"""

from __future__ import annotations

import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from smarts.core.errors import MapError, NetconvertError, ReplayError, ScenarioError
from smarts.core.spec.replay import REPLAY_MAP
from smarts.scenario import ScenarioSpec, map_path
from smarts.scenario.library import load_scenario
from smarts.scenario.map_check import map_problems


@dataclass
class Validation:
    """What validating one scenario found."""

    name: str
    """The name or path it was asked for."""
    problems: list[str] = field(default_factory=list)
    """One line each: ``file: field: message``."""
    spec: ScenarioSpec | None = None
    """The validated spec (None when the file itself is invalid)."""
    map_file: Path | None = None
    road_map: Any = None
    """The compiled map (None when it could not be built)."""

    @property
    def valid(self) -> bool:
        return not self.problems


def validate_scenario(
    name_or_path: str | os.PathLike,
    cache_dir: str | os.PathLike | None = None,
    limits: Any = None,
) -> Validation:
    """Validate a built-in scenario (by name) or a scenario file; see the module docstring.

    ``cache_dir`` holds built-in maps built by netconvert (the user cache when None); ``limits``
    (``ReachLimits``, the default car's when None) bounds the start speeds of agents whose action
    space obeys them.
    """
    result = Validation(os.fspath(name_or_path))
    try:
        spec = load_scenario(name_or_path)
    except ScenarioError as exc:
        result.problems = str(exc).splitlines()
        return result
    return validate_spec(spec, cache_dir, limits, result)


def validate_spec(
    spec: ScenarioSpec,
    cache_dir: str | os.PathLike | None = None,
    limits: Any = None,
    result: Validation | None = None,
) -> Validation:
    """The checks of :func:`validate_scenario` after reading: for a spec read or built elsewhere
    (a benchmark suite's inline scenarios)."""
    from smarts.dynamics.limits import ReachLimits

    result = result if result is not None else Validation(spec.source)
    result.spec = spec
    source = spec.source

    def add(where: str, error: Exception, one: bool = False) -> None:
        """Each line of ``error`` a problem, or (``one``) the whole message one problem with its
        further lines indented (a tool's output)."""
        lines = str(error).splitlines() or [type(error).__name__]
        if one:
            lines = [lines[0] + "".join(f"\n    {line}" for line in lines[1:])]
        for line in lines:
            result.problems.append(line if line.startswith(f"{source}: ") else f"{source}: {where}{line}")

    try:
        result.map_file = map_path(spec, cache_dir)
        if spec.map == REPLAY_MAP and spec.replay is not None:  # the recording's own lanes
            from smarts.replay import replay_road_map

            result.road_map = replay_road_map(spec.replay, spec.base_dir, source)
        else:
            from smarts.maps import load_map

            result.road_map = load_map(result.map_file)
    except (MapError, NetconvertError, ScenarioError, ReplayError, OSError) as exc:
        add("map: ", exc, one=True)
        return result
    road_map = result.road_map
    problems = map_problems(spec, road_map, limits if limits is not None else ReachLimits())
    result.problems += [f"{source}: {where}: {message}" for where, message in problems]
    if spec.traffic is not None and not any(where.startswith("traffic.") for where, _ in problems):
        try:
            _engine_check(spec, road_map, result.map_file)
        except (ScenarioError, MapError) as exc:
            add("", exc)
    taken: dict = {}
    if spec.replay is not None:  # ids, window and take-overs against the recording
        from smarts.replay import plan_replay

        try:
            taken = {t.agent_id: t for t in plan_replay(spec.replay, spec.base_dir, source).take_overs}
        except (ReplayError, ScenarioError) as exc:
            add("", exc)
    if not result.problems:  # a safety net: plan each route exactly as a reset will
        from smarts.core.missions import resolve_mission

        for i, agent in enumerate(spec.agents):
            try:
                mission = agent.mission
                if agent.id in taken:
                    from smarts.replay import take_over_mission

                    mission = take_over_mission(road_map, taken[agent.id], f"replay.take_over.{agent.id}")
                resolve_mission(road_map, agent.id, mission, f"agents[{i}].mission", spec.traffic)
            except MapError as exc:  # the simulation could not plan what the checks passed
                add("", exc)
    return result


def _engine_check(spec: ScenarioSpec, road_map: Any, map_file: Path) -> None:
    """The traffic engine's own checks, as it makes them at reset (the first problem raises)."""
    traffic = spec.traffic
    if traffic.engine == "sumo":
        from smarts.maps import sumo_net_path
        from smarts.traffic.sumo_routes import check_traffic

        check_traffic(traffic, road_map, sumo_net_path(map_file))
    else:
        from smarts.traffic.builtin import BuiltinTrafficProvider

        BuiltinTrafficProvider(traffic, road_map, spec.step_length)
