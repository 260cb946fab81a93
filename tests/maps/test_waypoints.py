"""Route paths, endless-route extension and waypoint paths."""

from __future__ import annotations

import numpy as np
import pytest

from smarts.maps import (
    MapError,
    RoadMap,
    extend_route,
    route_polyline,
    shortest_route,
    waypoint_paths,
)


def test_route_polyline_through_a_left_turn(cross_map: RoadMap) -> None:
    m = cross_map
    route = shortest_route(m, m.lane("WC_0"), m.lane("CN_0"))
    path = route_polyline(m, route, start_s=2.5)
    np.testing.assert_allclose(path.xy[0], [-97.5, -1.6], atol=1e-9)
    np.testing.assert_allclose(path.xy[-1], [1.6, 100.0], atol=1e-9)
    np.testing.assert_allclose(np.diff(path.s)[:-1], 1.0)
    assert 0 < path.s[-1] - path.s[-2] <= 1.0
    gaps = np.hypot(*np.diff(path.xy, axis=0).T)
    assert gaps.max() <= 1.0 + 1e-9
    assert path.heading[0] == pytest.approx(0.0)
    assert path.heading[-1] == pytest.approx(np.pi / 2)
    # Lanes appear in route order.
    order = {int(lane): i for i, lane in enumerate(route)}
    ranks = [order[int(lane)] for lane in path.lane]
    assert ranks == sorted(ranks) and set(ranks) == set(range(len(route)))


def test_route_polyline_blends_across_a_lane_change(straight_map: RoadMap) -> None:
    path = route_polyline(straight_map, np.array([0, 1]), start_s=50.0, spacing=0.5)
    np.testing.assert_allclose(path.xy[0], [50.0, -1.75])
    np.testing.assert_allclose(path.xy[-1], [200.0, 1.75])
    gaps = np.hypot(*np.diff(path.xy, axis=0).T)
    assert gaps.max() <= 0.5 + 1e-9  # no sideways jump
    assert np.all(np.diff(path.xy[:, 1]) >= -1e-12)  # moves monotonically to the left lane
    after = path.xy[:, 0] >= 60.0 + 1e-6
    np.testing.assert_allclose(path.xy[after, 1], 1.75)
    assert path.lane[0] == 0 and path.lane[-1] == 1
    assert np.all(np.diff(path.lane) >= 0)


def test_route_polyline_rejects_disconnected_lanes(cross_map: RoadMap) -> None:
    m = cross_map
    with pytest.raises(MapError, match="neither follows nor neighbours"):
        route_polyline(m, np.array([m.lane("WC_0"), m.lane("CN_0")]))


def test_extend_route_prefers_going_straight(cross_map: RoadMap) -> None:
    m = cross_map
    route = extend_route(m, m.lane("WC_0"), min_length=150.0)
    assert m.lane_ids[route[0]] == "WC_0" and m.lane_ids[route[-1]] == "CE_0"
    assert m.lane_road[route[-1]] == m.road("CE")
    assert extend_route(m, m.lane("WC_0"), min_length=50.0).tolist() == [m.lane("WC_0")]
    # A dead end stops the extension early.
    assert extend_route(m, m.lane("CE_0"), min_length=1e6).tolist() == [m.lane("CE_0")]


def test_waypoint_paths_one_per_lane_abreast(straight_map: RoadMap) -> None:
    paths = waypoint_paths(straight_map, np.array([100.0, -1.0]), 0.0, lookahead=10)
    assert len(paths) == 2
    for path, y in zip(paths, [-1.75, 1.75]):
        assert path.shape == (11, 4)
        np.testing.assert_allclose(path[:, 0], 100.0 + np.arange(11))
        np.testing.assert_allclose(path[:, 1], y)
        np.testing.assert_allclose(path[:, 2], 0.0)
    np.testing.assert_array_equal(paths[0][:, 3], 0)
    np.testing.assert_array_equal(paths[1][:, 3], 1)


def test_waypoint_paths_stop_at_a_dead_end(straight_map: RoadMap) -> None:
    paths = waypoint_paths(straight_map, np.array([195.5, -1.75]), 0.0, lookahead=20)
    assert [len(p) for p in paths] == [5, 5]
    np.testing.assert_allclose(paths[0][-1, 0], 199.5)


def test_waypoint_paths_branch_at_the_junction(cross_map: RoadMap) -> None:
    m = cross_map
    paths = waypoint_paths(m, np.array([-12.0, -1.6]), 0.0, lookahead=25)
    assert len(paths) == 3
    ends = {m.lane_ids[int(p[-1, 3])] for p in paths}
    assert ends == {"CN_0", "CE_0", "CS_0"}
    for p in paths:
        assert p.shape == (26, 4)
        np.testing.assert_allclose(p[0, :2], [-12.0, -1.6], atol=1e-9)
        assert np.hypot(*np.diff(p[:, :2], axis=0).T).max() <= 1.0 + 1e-9
        assert m.lane_internal[p[:, 3].astype(int)].any()


def test_waypoint_paths_follow_the_route(cross_map: RoadMap) -> None:
    m = cross_map
    route = shortest_route(m, m.lane("WC_0"), m.lane("CN_0"))
    paths = waypoint_paths(m, np.array([-12.0, -1.6]), 0.0, lookahead=25, route=route)
    assert len(paths) == 1
    lanes = paths[0][:, 3].astype(int)
    assert set(lanes) <= set(route.tolist())
    assert m.lane_ids[lanes[-1]] == "CN_0"
    assert paths[0][-1, 2] == pytest.approx(np.pi / 2)


def test_waypoint_paths_off_the_map_is_empty(cross_map: RoadMap) -> None:
    assert waypoint_paths(cross_map, np.array([500.0, 500.0]), 0.0) == []
