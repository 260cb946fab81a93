"""Road maps compiled to arrays: lanes, lane graph, spatial index, drivable raster, routes."""

from __future__ import annotations

from smarts.lazy_exports import lazy_exports

_EXPORTS = {
    "on_road": "drivable",
    "MapError": "errors",
    "MapWarning": "errors",
    "NoRouteError": "errors",
    "FORMAT_VERSION": "loader",
    "load_map": "loader",
    "sumo_net_path": "loader",
    "LaneProjection": "projection",
    "project": "projection",
    "RoadMap": "road_map",
    "route_between": "routing",
    "route_roads": "routing",
    "shortest_route": "routing",
    "RoutePath": "waypoints",
    "extend_route": "waypoints",
    "route_polyline": "waypoints",
    "waypoint_paths": "waypoints",
}
"""Public name -> submodule, imported on first use: a command that only names a map error (every
command-line tool does) need not load the compiled map code (about 0.6 s of imports)."""

__all__ = sorted(_EXPORTS)


__getattr__ = lazy_exports(__name__, _EXPORTS, globals())
