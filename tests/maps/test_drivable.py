"""Drivable-area raster and the O(1) on-road test."""

from __future__ import annotations

import numpy as np

from smarts.maps import RoadMap, on_road
from smarts.maps.drivable import build_drivable_raster


def test_lane_centres_are_on_road_and_far_points_are_not(straight_map: RoadMap) -> None:
    m = straight_map
    xy = np.array([[100.0, -1.75], [100.0, 1.75], [100.0, 11.75], [100.0, -11.75]])
    np.testing.assert_array_equal(on_road(m, xy), [True, True, False, False])


def test_lane_edges_and_sidewalk(straight_map: RoadMap) -> None:
    m = straight_map
    # Car lanes span y in [-3.5, 3.5]; the sidewalk (y in [-5.5, -3.5]) is not drivable.
    xy = np.array([[50.0, 3.3], [50.0, -3.3], [50.0, 3.9], [50.0, -4.5]])
    np.testing.assert_array_equal(on_road(m, xy), [True, True, False, False])


def test_outside_the_raster_and_nan_are_off_road(straight_map: RoadMap) -> None:
    xy = np.array([[-1e6, 0.0], [1e9, 1e9], [np.nan, 0.0], [0.0, np.inf]])
    assert not on_road(straight_map, xy).any()


def test_any_leading_shape_is_kept(cross_map: RoadMap) -> None:
    xy = np.array([[[0.0, 0.0], [-50.0, -1.6]], [[50.0, 10.0], [1.6, 50.0]]])
    result = on_road(cross_map, xy)
    assert result.shape == (2, 2)
    # The junction centre is drivable (junction outline), and so are lane centres.
    np.testing.assert_array_equal(result, [[True, True], [False, True]])


def test_every_lanepoint_is_on_road(cross_map: RoadMap) -> None:
    assert on_road(cross_map, cross_map.lanepoints).all()


def test_raster_coarsens_to_respect_the_cell_budget() -> None:
    poly = [np.array([[0.0, 0.0], [1000.0, 1000.0]])]
    origin, resolution, raster = build_drivable_raster(poly, np.array([4.0]), [], resolution=0.25, max_cells=100_000)
    assert raster.size <= 100_000
    assert resolution > 0.25
    assert raster.any()
    assert not raster[0].any() and not raster[-1].any()
    assert not raster[:, 0].any() and not raster[:, -1].any()


def test_lane_ends_are_on_road_but_beyond_a_dead_end_is_not(straight_map: RoadMap) -> None:
    xy = np.array([[200.0, -1.75], [0.0, 1.75], [203.0, -1.75], [-3.0, 1.75]])
    np.testing.assert_array_equal(on_road(straight_map, xy), [True, True, False, False])
