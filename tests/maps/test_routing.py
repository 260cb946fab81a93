"""Lane-graph routes, route masks and unreachable destinations."""

from __future__ import annotations

import numpy as np
import pytest

from smarts.maps import MapError, NoRouteError, RoadMap, route_between, route_roads, shortest_route


def is_link(m: RoadMap, a: int, b: int) -> bool:
    return b in m.successors(a) or b in (m.lane_left[a], m.lane_right[a])


def test_left_turn_goes_through_junction_lanes(cross_map: RoadMap) -> None:
    m = cross_map
    route = shortest_route(m, m.lane("WC_0"), m.lane("CN_0"))
    names = [m.lane_ids[i] for i in route]
    assert names[0] == "WC_0" and names[-1] == "CN_0"
    assert len(route) >= 3 and m.lane_internal[route[1:-1]].all()
    assert all(m.successors(a).tolist().count(b) == 1 for a, b in zip(route[:-1], route[1:]))
    # The junction lane ends heading north: it is really the left turn.
    last = m.lane_polyline(int(route[-2]))
    assert last[-1, 1] > last[-2, 1]
    assert route.dtype == np.int32


def test_route_changes_lane_when_needed(straight_map: RoadMap) -> None:
    route = shortest_route(straight_map, 0, 1)
    np.testing.assert_array_equal(route, [0, 1])
    assert shortest_route(straight_map, 1, 1).tolist() == [1]


def test_unreachable_lane_raises_naming_both_lanes(cross_map: RoadMap) -> None:
    m = cross_map
    with pytest.raises(NoRouteError, match="CE_0.*WC_0"):
        shortest_route(m, m.lane("CE_0"), m.lane("WC_0"))
    with pytest.raises(MapError, match="not a lane index"):
        shortest_route(m, 0, m.num_lanes + 5)


def test_route_between_positions(cross_map: RoadMap) -> None:
    m = cross_map
    route = route_between(m, np.array([-60.0, -1.6]), np.array([1.6, 60.0]), start_heading=0.0)
    assert m.lane_ids[route[0]] == "WC_0" and m.lane_ids[route[-1]] == "CN_0"
    assert all(is_link(m, int(a), int(b)) for a, b in zip(route[:-1], route[1:]))
    with pytest.raises(MapError, match="not near any lane"):
        route_between(m, np.array([-60.0, -1.6]), np.array([900.0, 900.0]))


def test_goal_behind_start_on_the_same_lane_has_no_route_on_a_dead_end(
    straight_map: RoadMap,
) -> None:
    with pytest.raises(NoRouteError, match="AB_1.*dead end"):
        route_between(straight_map, np.array([100.0, -1.75]), np.array([20.0, -1.75]))
    ahead = route_between(straight_map, np.array([20.0, -1.75]), np.array([100.0, -1.75]))
    assert ahead.tolist() == [0]


def test_route_roads_mask(cross_map: RoadMap) -> None:
    m = cross_map
    route = shortest_route(m, m.lane("WC_0"), m.lane("CE_0"))
    mask = route_roads(m, route)
    assert mask.shape == (len(m.road_ids),)
    on = {m.road_ids[i] for i in np.flatnonzero(mask)}
    assert {"WC", "CE"} <= on
    assert not {"CN", "CS", "CW", "EC", "NC", "SC"} & on
    # Only the junction road(s) joining WC to CE count, not the turns towards N or S.
    straight = [m.road_ids[m.lane_road[i]] for i in route if m.lane_internal[i]]
    assert set(straight) == on - {"WC", "CE"}
