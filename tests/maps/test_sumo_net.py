"""Compiling SUMO networks: lanes, topology, segments, grid, lanepoints and errors."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from smarts.maps import MapError, RoadMap
from smarts.maps.sumo_net import compile_sumo_net


def lane_names(m: RoadMap, lanes: np.ndarray) -> list[str]:
    return [m.lane_ids[int(i)] for i in lanes]


def test_straight_road_lanes_match_input_and_skip_sidewalk(straight_map: RoadMap) -> None:
    m = straight_map
    assert m.lane_ids == ["AB_1", "AB_2"]  # AB_0 is the sidewalk
    assert m.road_ids == ["AB"]
    np.testing.assert_array_equal(m.lane_index, [0, 1])
    np.testing.assert_allclose(m.lane_width, [3.5, 3.5])
    np.testing.assert_allclose(m.lane_speed_limit, [20.0, 20.0])
    np.testing.assert_allclose(m.lane_length, [200.0, 200.0])
    assert not m.lane_internal.any()
    np.testing.assert_allclose(m.lane_polyline(0), [[0.0, -1.75], [200.0, -1.75]])
    np.testing.assert_allclose(m.lane_polyline(1), [[0.0, 1.75], [200.0, 1.75]])


def test_neighbours_index_plus_one_is_left(straight_map: RoadMap) -> None:
    np.testing.assert_array_equal(straight_map.lane_left, [1, -1])
    np.testing.assert_array_equal(straight_map.lane_right, [-1, 0])


def test_cross_has_internal_lanes_and_successors_go_through_them(cross_map: RoadMap) -> None:
    m = cross_map
    normal = [m.lane_ids[i] for i in np.flatnonzero(~m.lane_internal)]
    assert sorted(normal) == sorted(f"{a}{b}_0" for a, b in ["WC", "CW", "EC", "CE", "NC", "CN", "SC", "CS"])
    internal = np.flatnonzero(m.lane_internal)
    assert len(internal) >= 12  # right, straight and left from each of 4 approaches
    assert all(m.lane_ids[i].startswith(":") for i in internal)
    assert all(m.road_ids[m.lane_road[i]].startswith(":") for i in internal)

    wc = m.lane("WC_0")
    firsts = m.successors(wc)
    assert len(firsts) == 3 and m.lane_internal[firsts].all()
    # Following internal lanes from WC_0 reaches exactly the three outgoing roads except back west.
    reached = set()
    for lane in firsts:
        frontier = [int(lane)]
        while frontier:
            cur = frontier.pop()
            for nxt in m.successors(cur):
                if m.lane_internal[nxt]:
                    frontier.append(int(nxt))
                else:
                    reached.add(m.lane_ids[nxt])
    assert reached == {"CN_0", "CE_0", "CS_0"}
    assert len(m.successors(m.lane("CE_0"))) == 0  # dead end at E

    # Predecessors mirror successors.
    for lane in range(m.num_lanes):
        for nxt in m.successors(lane):
            assert lane in m.predecessors(int(nxt))


def test_segments_and_point_s_are_consistent(cross_map: RoadMap) -> None:
    m = cross_map
    np.testing.assert_allclose(m.seg_len, np.hypot(m.seg_vec[:, 0], m.seg_vec[:, 1]))
    assert len(m.seg_start) == len(m.points) - m.num_lanes
    for lane in range(m.num_lanes):
        segs = np.flatnonzero(m.seg_lane == lane)
        np.testing.assert_allclose(m.seg_len[segs].sum(), m.lane_length[lane])
        np.testing.assert_allclose(m.seg_s0[segs][0], 0.0)
    np.testing.assert_allclose(m.lane_length[m.lane("WC_0")], 92.8)


def test_grid_lists_every_segment_within_margin(cross_map: RoadMap) -> None:
    m = cross_map
    rng = np.random.default_rng(3)
    pts = rng.uniform(m.bounds[:2], m.bounds[2:], size=(400, 2))
    for p in pts:
        rel = p - m.seg_start
        u = np.clip((rel * m.seg_vec).sum(1) / (m.seg_len**2), 0, 1)
        dist = np.hypot(*(rel - u[:, None] * m.seg_vec).T)
        near = set(np.flatnonzero(dist <= m.grid_margin))
        ix, iy = np.floor((p - m.grid_origin) / m.grid_cell).astype(int)
        cell = ix * m.grid_shape[1] + iy
        listed = set(m.grid_segs[m.grid_offsets[cell] : m.grid_offsets[cell + 1]])
        assert near <= listed
    assert m.grid_margin >= m.lane_width.max()


def test_lanepoints_are_about_one_metre_apart_and_cover_both_ends(cross_map: RoadMap) -> None:
    m = cross_map
    for lane in range(m.num_lanes):
        xy, s, heading = m.lane_lanepoints(lane)
        gaps = np.hypot(*np.diff(xy, axis=0).T)
        assert gaps.max() <= 1.0 + 1e-9
        ds = np.diff(s)
        np.testing.assert_allclose(ds, ds[0])  # even spacing along the lane...
        assert ds[0] <= 1.0 + 1e-9  # ...of at most 1 m
        if m.lane_length[lane] > 2:
            assert ds[0] > 0.8
        assert s[0] == 0.0 and s[-1] == pytest.approx(m.lane_length[lane])
        poly = m.lane_polyline(lane)
        np.testing.assert_allclose(xy[0], poly[0])
        np.testing.assert_allclose(xy[-1], poly[-1])
    xy, _, heading = m.lane_lanepoints(m.lane("WC_0"))
    np.testing.assert_allclose(heading, 0.0, atol=1e-12)
    _, _, heading = m.lane_lanepoints(m.lane("CN_0"))
    np.testing.assert_allclose(heading, np.pi / 2)


def test_bounds_and_junction_shapes(cross_map: RoadMap) -> None:
    m = cross_map
    assert m.bounds[0] <= -100 and m.bounds[2] >= 100
    assert m.bounds[1] <= -100 and m.bounds[3] >= 100
    assert len(m.junction_shapes) == 1  # only C; the four dead ends have no outline
    centre = m.junction_shapes[0]
    assert np.abs(centre).max() < 10


# ---------------------------------------------------------------------------------- errors
def test_missing_file_names_the_file(tmp_path: Path) -> None:
    path = tmp_path / "nowhere.net.xml"
    with pytest.raises(MapError, match="nowhere.net.xml.*not found"):
        compile_sumo_net(path)


def test_not_xml_names_the_file(tmp_path: Path) -> None:
    path = tmp_path / "garbage.net.xml"
    path.write_text("this is <not xml")
    with pytest.raises(MapError, match="garbage.net.xml.*not a valid XML"):
        compile_sumo_net(path)


def test_wrong_root_is_rejected(tmp_path: Path) -> None:
    path = tmp_path / "nodes.net.xml"
    path.write_text("<nodes><node id='a' x='0' y='0'/></nodes>")
    with pytest.raises(MapError, match="nodes.net.xml.*root <net>"):
        compile_sumo_net(path)


def test_network_without_lanes_is_rejected(tmp_path: Path) -> None:
    path = tmp_path / "empty.net.xml"
    path.write_text('<net version="1.20"><edge id="x" function="walkingarea"/></net>')
    with pytest.raises(MapError, match="empty.net.xml.*no lanes"):
        compile_sumo_net(path)


def test_bad_shape_names_file_and_lane(tmp_path: Path, straight_net: Path) -> None:
    text = straight_net.read_text().replace('shape="0.00,1.75 200.00,1.75"', 'shape="0.00,1.75 200.00;1.75"')
    assert "200.00;1.75" in text
    path = tmp_path / "bad_shape.net.xml"
    path.write_text(text)
    with pytest.raises(MapError, match=r"bad_shape.net.xml.*'AB_2'.*malformed shape"):
        compile_sumo_net(path)


def test_bad_width_names_file_and_lane(tmp_path: Path, straight_net: Path) -> None:
    text = straight_net.read_text().replace('width="3.50"', 'width="wide"', 1)
    path = tmp_path / "bad_width.net.xml"
    path.write_text(text)
    with pytest.raises(MapError, match=r"bad_width.net.xml.*'AB_1'.*'width'"):
        compile_sumo_net(path)


def test_sumo_lane_lengths_are_kept_and_offsets_convert_both_ways(tmp_path) -> None:
    """SUMO's lane ``length`` (here the edge's length attribute, 120 m on a 100 m shape) is
    kept next to the shape's length; offsets scale between the two."""
    from tests.maps.conftest import build_net

    nodes = '<nodes><node id="A" x="0" y="0"/><node id="B" x="100" y="0"/></nodes>'
    edges = '<edges><edge id="AB" from="A" to="B" numLanes="1" length="120"/></edges>'
    m = compile_sumo_net(build_net(tmp_path, "long", nodes, edges))
    lane = m.lane("AB_0")
    assert m.lane_length[lane] == pytest.approx(100.0)
    assert m.lane_sumo_length[lane] == pytest.approx(120.0)
    assert m.to_sumo_pos(lane, 50.0) == pytest.approx(60.0)
    assert m.from_sumo_pos(lane, 60.0) == pytest.approx(50.0)
    assert m.to_sumo_pos(lane, 130.0) == pytest.approx(120.0)  # clamped to the lane
    assert m.from_sumo_pos(lane, -1.0) == 0.0


def test_lanes_without_a_length_attribute_use_their_shape(straight_map) -> None:
    np.testing.assert_allclose(straight_map.lane_sumo_length, straight_map.lane_length, atol=0.01)
