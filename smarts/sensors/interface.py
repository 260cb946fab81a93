"""The agent interface (which sensors an agent has and how big their outputs are), defined with the
rest of the scenario spec in ``smarts.core.spec.interface`` and named here for the sensors' users."""

from smarts.core.errors import InterfaceError
from smarts.core.spec.interface import (
    OCCLUSION_MODES,
    RASTER_LAYERS,
    AgentInterface,
    EgoInterface,
    LidarInterface,
    NeighboursInterface,
    OcclusionInterface,
    RasterInterface,
    WaypointsInterface,
    interface_from_dict,
    interface_to_dict,
)

__all__ = [
    "OCCLUSION_MODES",
    "RASTER_LAYERS",
    "AgentInterface",
    "InterfaceError",
    "EgoInterface",
    "LidarInterface",
    "NeighboursInterface",
    "OcclusionInterface",
    "RasterInterface",
    "WaypointsInterface",
    "interface_from_dict",
    "interface_to_dict",
]
