"""Sensors: agent interfaces and the batched observation (ego, neighbours, waypoints, occlusion,
rasters, lidar), plus the renderers.

Only the interface models (``smarts.core.spec.interface``) are imported here, so importing the
package does not load the compiled sensors.
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
