"""The scenario spec: what a YAML scenario file may say, as dataclasses, strictly validated.

The dataclasses themselves are plain data in ``smarts.core.spec`` (every layer reads them); this
module's :class:`ScenarioSpec` is that dataclass plus reading (``from_yaml``, ``from_dict``: see
``smarts.scenario.reader``), writing (``to_dict``, ``to_yaml``: ``smarts.scenario.writer``), the map
file to load (``map_path``) and the check against the compiled map (``check_map``:
``smarts.scenario.map_check``). Each error names the file and the dotted field path
(``agents[1].mission.goal.radius``) and says what was expected.
"""

from __future__ import annotations

import os
from collections.abc import Mapping
from pathlib import Path
from typing import Any

from smarts.core.spec import scenario as _core
from smarts.core.spec.replay import REPLAY_MAP
from smarts.core.spec.scenario import (
    ACTION_SPACES,
    BUILTIN_PREFIX,
    CONTROLLERS,
    DEFAULT_TERMINATE_ON,
    LANE_RELATIVE_SPACES,
    MISSION_END_ACTIONS,
    TERMINATION_EVENTS,
    VEHICLE_TYPES,
    AgentSpec,
    EventsSpec,
    GoalSpec,
    MissionSpec,
    RewardSpec,
    StartSpec,
    VehicleDimensions,
    VehicleSpec,
)
from smarts.core.spec.traffic import TRAFFIC_VEHICLE_BASES
from smarts.scenario.builtin_maps import builtin_map_path
from smarts.scenario.map_check import check_scenario_map
from smarts.scenario.reader import (
    MAP_FILE_SUFFIXES,
    ZOO_PREFIX,
    read_scenario,
    read_scenario_file,
    resolve_map_file,
)
from smarts.scenario.writer import scenario_to_dict, scenario_to_yaml

__all__ = [
    "ACTION_SPACES",
    "BUILTIN_PREFIX",
    "CONTROLLERS",
    "DEFAULT_TERMINATE_ON",
    "LANE_RELATIVE_SPACES",
    "MAP_FILE_SUFFIXES",
    "MISSION_END_ACTIONS",
    "TERMINATION_EVENTS",
    "TRAFFIC_VEHICLE_BASES",
    "VEHICLE_TYPES",
    "ZOO_PREFIX",
    "AgentSpec",
    "EventsSpec",
    "GoalSpec",
    "MissionSpec",
    "RewardSpec",
    "ScenarioSpec",
    "StartSpec",
    "VehicleDimensions",
    "VehicleSpec",
]


class ScenarioSpec(_core.ScenarioSpec):
    """A whole scenario (the fields of :class:`smarts.core.spec.ScenarioSpec`), read from and
    written to YAML."""

    # ------------------------------------------------------------------ reading
    @classmethod
    def from_yaml(cls, path: str | os.PathLike) -> ScenarioSpec:
        return read_scenario_file(path, cls)

    @classmethod
    def from_dict(
        cls,
        data: Mapping[str, Any],
        source: str = "<dict>",
        base_dir: str | os.PathLike | None = None,
    ) -> ScenarioSpec:
        """Validate a plain mapping (as loaded from YAML) into a spec.

        ``source`` prefixes error messages; a relative map path is resolved against ``base_dir``
        (the current directory when None).
        """
        return read_scenario(data, source, base_dir, cls)

    # ------------------------------------------------------------------ writing
    def to_dict(self) -> dict[str, Any]:
        """Plain data (lists, dicts, scalars) that ``from_dict`` turns back into an equal spec."""
        return scenario_to_dict(self)

    def to_yaml(self) -> str:
        return scenario_to_yaml(self)

    # ------------------------------------------------------------------ map
    def map_path(self, cache_dir: str | os.PathLike | None = None) -> Path:
        """The map file to load: a built-in map is compiled (and cached) by netconvert first."""
        if self.builtin_map is not None:
            return builtin_map_path(self.builtin_map, cache_dir)
        if self.map == REPLAY_MAP and self.replay is not None:  # the dataset's map: its recording
            from smarts.replay.load import replay_path

            return replay_path(self.replay, self.base_dir)
        return resolve_map_file(self.map, self.base_dir)

    def check_map(self, road_map: Any, limits: Any = None) -> None:
        """Check the missions and traffic against the map; one ``ScenarioError`` lists every
        problem (roads, lanes, offsets, speeds against the lanes' limits, routes from each start to
        its goal and along each flow and trip; see ``smarts.scenario.map_check``).

        ``road_map`` needs ``road_index_of``, ``road_lanes(road)`` and ``lane_length`` (and uses
        the speed limits, lane graph, ``lane_internal`` and ``bounds`` when present), as on
        :class:`smarts.maps.road_map.RoadMap`. ``limits`` (``ReachLimits``) also bounds the start
        speeds of agents whose action space obeys them.
        """
        check_scenario_map(self, road_map, limits)
