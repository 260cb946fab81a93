"""Shared fixtures: every built-in map compiled once per session by the real netconvert."""

from __future__ import annotations

from dataclasses import fields
from pathlib import Path

import numpy as np
import pytest
import sumolib
import yaml

from smarts.maps.road_map import RoadMap
from smarts.scenario import list_scenarios, load_scenario, scenario_path
from smarts.scenario.builtin_maps import BUILTIN_MAPS, builtin_map_path


@pytest.fixture(scope="session")
def map_cache_dir(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return tmp_path_factory.mktemp("smarts_cache")


@pytest.fixture(scope="session")
def built_maps(map_cache_dir: Path) -> dict[str, Path]:
    """name -> .net.xml of every built-in map, compiled into a private cache."""
    return {name: builtin_map_path(name, map_cache_dir) for name in BUILTIN_MAPS}


@pytest.fixture(scope="session")
def sumo_nets(built_maps: dict[str, Path]) -> dict[str, sumolib.net.Net]:
    return {name: sumolib.net.readNet(str(path), withInternal=True) for name, path in built_maps.items()}


def _lane_table_map(path: Path, net: sumolib.net.Net) -> RoadMap:
    """A RoadMap holding the lane table of a netconvert output (geometry arrays left empty).

    It is enough for ``ScenarioSpec.check_map``, which reads roads, lane counts and lengths.
    """
    road_ids, lane_ids, lane_road, lane_index, lane_length, lane_internal = [], [], [], [], [], []
    for edge in net.getEdges(withInternal=True):
        road_ids.append(edge.getID())
        for lane in edge.getLanes():
            lane_ids.append(lane.getID())
            lane_road.append(len(road_ids) - 1)
            lane_index.append(lane.getIndex())
            lane_length.append(lane.getLength())
            lane_internal.append(edge.getFunction() == "internal")
    (xmin, ymin, xmax, ymax) = net.getBoundary()
    given = {
        "source": str(path),
        "content_hash": "",
        "lane_ids": lane_ids,
        "road_ids": road_ids,
        "lane_road": np.array(lane_road, dtype=np.int32),
        "lane_index": np.array(lane_index, dtype=np.int16),
        "lane_length": np.array(lane_length),
        "lane_internal": np.array(lane_internal),
        "bounds": np.array([xmin, ymin, xmax, ymax]),
        "grid_cell": 1.0,
        "grid_shape": (0, 0),
        "grid_margin": 0.0,
        "raster_resolution": 1.0,
    }
    kwargs = {}
    for f in fields(RoadMap):
        if f.name in given:
            kwargs[f.name] = given[f.name]
        elif f.name not in ("junction_shapes", "lane_index_of", "road_index_of"):
            kwargs[f.name] = np.zeros(0)
    return RoadMap(**kwargs)


@pytest.fixture(scope="session")
def lane_table_maps(built_maps, sumo_nets) -> dict[str, RoadMap]:
    return {name: _lane_table_map(built_maps[name], sumo_nets[name]) for name in built_maps}


def _library_map(name: str) -> str:
    """The built-in map a library scenario names, read from the raw YAML (without validating)."""
    data = yaml.safe_load(scenario_path(name).read_text(encoding="utf-8"))
    return str(data["map"]).removeprefix("builtin:")


@pytest.fixture
def library_scenario():
    """``load(name)``: a library scenario; its built-in map must exist (no skipping)."""

    def load(name: str):
        map_name = _library_map(name)
        assert map_name in BUILTIN_MAPS, f"scenario {name!r} names the unknown built-in map {map_name!r}"
        return load_scenario(name)

    return load


@pytest.fixture
def library_maps_available():
    """Every library scenario's built-in map exists (a failure, not a skip, when one does not)."""
    missing = {n: m for n in list_scenarios() if (m := _library_map(n)) not in BUILTIN_MAPS}
    assert not missing, f"library scenarios name unknown built-in maps: {missing}"
