"""Scenarios: the YAML spec, the built-in maps (generated, compiled by netconvert) and library."""

from smarts.scenario.builtin_maps import (
    BUILTIN_MAPS,
    MapRecipe,
    builtin_map_path,
    compile_map,
)
from smarts.scenario.errors import NetconvertError, ScenarioError
from smarts.scenario.library import list_scenarios, load_scenario, scenario_path
from smarts.scenario.spec import (
    ACTION_SPACES,
    TERMINATION_EVENTS,
    VEHICLE_TYPES,
    AgentSpec,
    EventsSpec,
    GoalSpec,
    MissionSpec,
    RewardSpec,
    ScenarioSpec,
    StartSpec,
    VehicleDimensions,
    VehicleSpec,
)

__all__ = [
    "ACTION_SPACES",
    "BUILTIN_MAPS",
    "TERMINATION_EVENTS",
    "VEHICLE_TYPES",
    "AgentSpec",
    "EventsSpec",
    "GoalSpec",
    "MapRecipe",
    "MissionSpec",
    "NetconvertError",
    "RewardSpec",
    "ScenarioError",
    "ScenarioSpec",
    "StartSpec",
    "VehicleDimensions",
    "VehicleSpec",
    "builtin_map_path",
    "compile_map",
    "list_scenarios",
    "load_scenario",
    "scenario_path",
]
