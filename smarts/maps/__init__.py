"""Road maps compiled to arrays: lanes, lane graph, spatial index, drivable raster, routes."""

from smarts.maps.drivable import on_road
from smarts.maps.errors import MapError, MapWarning, NoRouteError
from smarts.maps.loader import FORMAT_VERSION, load_map, sumo_net_path
from smarts.maps.projection import LaneProjection, project
from smarts.maps.road_map import RoadMap
from smarts.maps.routing import route_between, route_roads, shortest_route
from smarts.maps.waypoints import RoutePath, extend_route, route_polyline, waypoint_paths

__all__ = [
    "FORMAT_VERSION",
    "LaneProjection",
    "MapError",
    "MapWarning",
    "NoRouteError",
    "RoadMap",
    "RoutePath",
    "extend_route",
    "load_map",
    "on_road",
    "project",
    "route_between",
    "route_polyline",
    "route_roads",
    "shortest_route",
    "sumo_net_path",
    "waypoint_paths",
]
