"""The traffic spec datatypes, defined in ``smarts.core.spec.traffic``; kept here so existing imports
keep working."""

from smarts.core.spec.traffic import (
    DEFAULT_VEHICLE_TYPES,
    DENSITY_LEVELS,
    DENSITY_RATES,
    DEPART_LANES,
    DEPART_SPEEDS,
    TRAFFIC_ENGINES,
    TRAFFIC_VEHICLE_BASES,
    FlowSpec,
    PedestrianFlowSpec,
    TrafficSpec,
    TripSpec,
    VehicleTypeSpec,
)

__all__ = [
    "DEFAULT_VEHICLE_TYPES",
    "DENSITY_LEVELS",
    "DENSITY_RATES",
    "DEPART_LANES",
    "DEPART_SPEEDS",
    "TRAFFIC_ENGINES",
    "TRAFFIC_VEHICLE_BASES",
    "FlowSpec",
    "PedestrianFlowSpec",
    "TrafficSpec",
    "TripSpec",
    "VehicleTypeSpec",
]
