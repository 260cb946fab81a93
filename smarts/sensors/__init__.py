"""Sensors: agent interfaces and the batched observation (ego, neighbours, waypoints, occlusion,
rasters, lidar), plus the renderers.

Only the plain interface dataclasses are imported here, so the scenario reader can use them
without loading the compiled sensors.
"""

from smarts.core.errors import InterfaceError
from smarts.sensors.interface import (
    AgentInterface,
    EgoInterface,
    LidarInterface,
    NeighboursInterface,
    OcclusionInterface,
    RasterInterface,
    WaypointsInterface,
)

__all__ = [
    "AgentInterface",
    "EgoInterface",
    "InterfaceError",
    "LidarInterface",
    "NeighboursInterface",
    "OcclusionInterface",
    "RasterInterface",
    "WaypointsInterface",
]
