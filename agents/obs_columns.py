"""Named columns of the observation arrays that the agents read (``smarts.sensors.observation``).

Agents never import the simulator, so the layout they rely on is written down here once, and
``tests/agents/test_obs_columns.py`` checks that it equals the names the env builds its
observation with. Index with the names, never with bare numbers:
``obs["ego"][:, Ego.SPEED]``, ``row["neighbours"][i, Neighbour.LENGTH]``,
``row["neighbours"][:, NEIGHBOUR_XY]``, ``obs["waypoints"][:, WaypointPath.ROUTE, k, Waypoint.HEADING]``.

Only the columns of the default interface are named; the extended ego and neighbour columns
(``ego.extended``, ``neighbours.extended``, occlusion's visible fraction) come after them, so
these indices hold with every interface.
"""

from __future__ import annotations

from enum import IntEnum, unique


@unique
class Ego(IntEnum):
    """``ego`` [12]: the agent's own vehicle."""

    SPEED = 0  # m/s
    ACCEL = 1  # longitudinal acceleration, m/s^2
    JERK = 2  # longitudinal jerk, m/s^3
    LAT_ACCEL = 3  # lateral acceleration, m/s^2
    YAW_RATE = 4  # rad/s
    STEERING = 5  # rad
    HEADING_ERROR = 6  # heading relative to the lane, rad
    LANE_OFFSET = 7  # lateral offset from the lane centre, m (+ left)
    LANE_WIDTH = 8  # m
    SPEED_LIMIT = 9  # the lane's, m/s
    LENGTH = 10  # vehicle length, m
    WIDTH = 11  # vehicle width, m


@unique
class Neighbour(IntEnum):
    """``neighbours`` [K, 9+]: one row per nearby road user, ego frame (``neighbour_mask`` marks rows)."""

    DX = 0  # m, forward
    DY = 1  # m, left
    COS_HEADING = 2  # of the heading relative to the ego's
    SIN_HEADING = 3
    VX = 4  # velocity relative to the ego, m/s
    VY = 5
    LENGTH = 6  # m
    WIDTH = 7  # m
    PEDESTRIAN = 8  # 1 for a pedestrian, 0 for a vehicle


@unique
class Goal(IntEnum):
    """``goal`` [4]."""

    DX = 0  # goal position, ego frame, m
    DY = 1
    ROUTE_LEFT = 2  # route distance left, m
    HAS_GOAL = 3  # 1 if the mission has a goal (0: endless)


@unique
class Signal(IntEnum):
    """``signal`` [4] (interface ``signals: true``): the next traffic signal on the route."""

    RED = 0  # one of red, yellow, green is 1 (all 0 when there is none ahead)
    YELLOW = 1
    GREEN = 2
    STOP_DISTANCE = 3  # route distance to its stop line, m (0 when none)


@unique
class WaypointPath(IntEnum):
    """The first index of ``waypoints`` [3, W, 3] and ``waypoint_mask`` [3, W]: which path."""

    ROUTE = 0  # along the route
    LEFT = 1  # the lane left of it
    RIGHT = 2  # the lane right of it


@unique
class Waypoint(IntEnum):
    """The last index of ``waypoints``: one point of a path, ego frame."""

    X = 0  # m
    Y = 1  # m
    HEADING = 2  # relative to the ego's, rad


NEIGHBOUR_XY = slice(Neighbour.DX.value, Neighbour.DY.value + 1)
"""``neighbours[..., NEIGHBOUR_XY]``: the (dx, dy) position columns."""
GOAL_XY = slice(Goal.DX.value, Goal.DY.value + 1)
"""``goal[..., GOAL_XY]``: the goal's (dx, dy)."""


def column_names(layout: type[IntEnum]) -> tuple[str, ...]:
    """The column names of ``layout`` in order, spelt as the env spells them (``Ego`` ->
    ``("speed", "accel", ...)``)."""
    return tuple(member.name.lower() for member in sorted(layout, key=int))
