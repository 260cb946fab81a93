"""Batched projection of points onto lanes."""

from __future__ import annotations

import numpy as np
import pytest

from smarts.maps import RoadMap, project


def through_lane(m: RoadMap, src: str, dst: str) -> int:
    """The junction lane leading from lane ``src`` to lane ``dst``."""
    for lane in m.successors(m.lane(src)):
        if m.lane(dst) in m.successors(int(lane)):
            return int(lane)
    raise AssertionError(f"no junction lane from {src} to {dst}")


def test_straight_road_points(straight_map: RoadMap) -> None:
    m = straight_map
    xy = np.array([[100.0, -1.25], [100.0, 1.55], [37.5, -1.75], [150.0, 3.0]])
    p = project(m, xy, np.zeros(4))
    np.testing.assert_array_equal(p.lane, [0, 1, 0, 1])
    np.testing.assert_allclose(p.s, [100.0, 100.0, 37.5, 150.0], atol=1e-9)
    np.testing.assert_allclose(p.t, [0.5, -0.2, 0.0, 1.25], atol=1e-9)
    np.testing.assert_allclose(p.lane_heading, 0.0)
    np.testing.assert_allclose(p.distance, np.abs(p.t), atol=1e-9)
    assert p.lane.dtype == np.int32


def test_cross_points_on_normal_lanes(cross_map: RoadMap) -> None:
    m = cross_map
    p = project(m, np.array([[50.0, -1.0], [-50.0, 1.6], [1.6, 60.0]]), np.array([0, np.pi, 1.5]))
    assert [m.lane_ids[i] for i in p.lane] == ["CE_0", "CW_0", "CN_0"]
    np.testing.assert_allclose(p.s, [42.8, 42.8, 52.8], atol=1e-6)
    np.testing.assert_allclose(p.t, [0.6, 0.0, 0.0], atol=1e-6)
    np.testing.assert_allclose(p.lane_heading, [0.0, np.pi, np.pi / 2], atol=1e-9)


def test_heading_separates_overlapping_junction_lanes(cross_map: RoadMap) -> None:
    m = cross_map
    xy = np.array([[1.9, 0.5], [1.9, 0.5]])
    p = project(m, xy, np.array([np.pi / 2, np.pi]))
    assert p.lane[0] == through_lane(m, "SC_0", "CN_0")
    assert p.lane[1] == through_lane(m, "EC_0", "CW_0")
    # Northbound straight runs along x = 1.6 from y = -7.2; westbound along y = 1.6 from x = 7.2.
    np.testing.assert_allclose(p.s, [7.7, 5.3], atol=1e-6)
    np.testing.assert_allclose(p.t, [-0.3, 1.1], atol=1e-6)
    np.testing.assert_allclose(p.lane_heading, [np.pi / 2, np.pi], atol=1e-9)


def test_without_heading_the_nearest_lane_wins(cross_map: RoadMap) -> None:
    m = cross_map
    p = project(m, np.array([[30.0, 1.2]]))
    assert m.lane_ids[p.lane[0]] == "EC_0"
    assert p.distance[0] == pytest.approx(0.4)


def test_off_lane_point_takes_nearest_and_far_point_has_no_lane(cross_map: RoadMap) -> None:
    m = cross_map
    p = project(m, np.array([[50.0, -5.0], [1000.0, 1000.0], [np.nan, 0.0]]), np.zeros(3))
    assert m.lane_ids[p.lane[0]] == "CE_0"
    assert p.t[0] == pytest.approx(-3.4)
    assert p.distance[0] == pytest.approx(3.4)
    np.testing.assert_array_equal(p.lane[1:], [-1, -1])
    assert np.isinf(p.distance[1:]).all()
    np.testing.assert_array_equal(p.s[1:], 0.0)


def test_s_extends_past_the_ends_of_a_lane(straight_map: RoadMap) -> None:
    p = project(straight_map, np.array([[-2.0, -1.0], [203.0, -2.0]]))
    np.testing.assert_allclose(p.s, [-2.0, 203.0], atol=1e-9)
    np.testing.assert_allclose(p.t, [0.75, -0.25], atol=1e-9)


def test_batch_matches_single_points(cross_map: RoadMap) -> None:
    m = cross_map
    rng = np.random.default_rng(7)
    xy = rng.uniform(-30, 30, size=(60, 2))
    heading = rng.uniform(-np.pi, np.pi, size=60)
    batch = project(m, xy, heading)
    for i in range(len(xy)):
        one = project(m, xy[i : i + 1], heading[i : i + 1])
        for a, b in zip(batch, one):
            np.testing.assert_allclose(a[i], b[0])


def test_nearest_matches_brute_force(cross_map: RoadMap) -> None:
    m = cross_map
    rng = np.random.default_rng(11)
    xy = rng.uniform(-110, 110, size=(2000, 2))
    p = project(m, xy)
    rel = xy[:, None, :] - m.seg_start[None]
    u = np.clip((rel * m.seg_vec).sum(-1) / m.seg_len**2, 0, 1)
    dist = np.linalg.norm(rel - u[..., None] * m.seg_vec, axis=-1).min(axis=1)
    close = dist <= m.grid_margin
    assert close.sum() > 100
    np.testing.assert_allclose(p.distance[close], dist[close], atol=1e-9)
    # Every point on a lane surface reports |t| within half that lane's width.
    on = p.distance <= m.lane_width[np.maximum(p.lane, 0)] / 2
    assert np.all(np.abs(p.t[on]) <= m.lane_width[p.lane[on]] / 2 + 1e-9)


def test_nan_heading_and_empty_input(cross_map: RoadMap) -> None:
    m = cross_map
    xy = np.array([[50.0, -1.0], [-50.0, 1.6]])
    p = project(m, xy, np.array([np.nan, np.pi]))
    assert p.lane[0] == -1 and m.lane_ids[p.lane[1]] == "CW_0"
    assert project(m, xy[:1], np.array([np.nan])).lane[0] == -1
    assert project(m, xy, np.array([np.nan, np.nan])).lane.tolist() == [-1, -1]
    empty = project(m, np.zeros((0, 2)))
    assert empty.lane.shape == (0,) and empty.s.shape == (0,)
