"""Scenarios: the YAML spec (reader and writer of the ``smarts.core.spec`` dataclasses), the built-in
maps (generated, compiled by netconvert) and library."""

from smarts.core.errors import NetconvertError, ScenarioError
from smarts.core.spec import (
    ACTION_SPACES,
    DEFAULT_VEHICLE_TYPES,
    DENSITY_LEVELS,
    MISSION_END_ACTIONS,
    TERMINATION_EVENTS,
    TRAFFIC_ENGINES,
    VEHICLE_TYPES,
    AgentSpec,
    EventsSpec,
    FlowSpec,
    GoalSpec,
    MissionSpec,
    PedestrianFlowSpec,
    RewardSpec,
    StartSpec,
    TrafficSpec,
    TripSpec,
    VehicleDimensions,
    VehicleSpec,
    VehicleTypeSpec,
)
from smarts.scenario.builtin_maps import (
    BUILTIN_MAPS,
    MapRecipe,
    builtin_map_path,
    compile_map,
)
from smarts.scenario.library import list_scenarios, load_scenario, scenario_path
from smarts.scenario.spec import ScenarioSpec

__all__ = [
    "ACTION_SPACES",
    "BUILTIN_MAPS",
    "DEFAULT_VEHICLE_TYPES",
    "DENSITY_LEVELS",
    "MISSION_END_ACTIONS",
    "TERMINATION_EVENTS",
    "TRAFFIC_ENGINES",
    "VEHICLE_TYPES",
    "AgentSpec",
    "EventsSpec",
    "FlowSpec",
    "GoalSpec",
    "MapRecipe",
    "MissionSpec",
    "NetconvertError",
    "PedestrianFlowSpec",
    "RewardSpec",
    "ScenarioError",
    "ScenarioSpec",
    "StartSpec",
    "TrafficSpec",
    "TripSpec",
    "VehicleDimensions",
    "VehicleSpec",
    "VehicleTypeSpec",
    "builtin_map_path",
    "compile_map",
    "list_scenarios",
    "load_scenario",
    "scenario_path",
]
