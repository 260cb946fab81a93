"""Several maps in one lane index space: each map's window answers as the map itself, shifted."""

import numpy as np
import pytest

from smarts.core.missions import resolve_mission
from smarts.core.spec.traffic import TrafficSpec
from smarts.maps import load_map, project, shortest_route
from smarts.maps.drivable import raster_lookup
from smarts.maps.stack import stack_maps
from smarts.scenario.builtin_maps import builtin_map_path
from smarts.traffic.builtin.junctions import junction_table
from smarts.traffic.density import density_flows
from smarts.traffic.signals import SignalState
from tests.builders import agent, make_spec

NAMES = ("straight_3lane", "intersection_4way_2lane_signal", "t_junction")


@pytest.fixture(scope="module")
def maps():
    return [load_map(builtin_map_path(name)) for name in NAMES]


@pytest.fixture(scope="module")
def stack(maps):
    return stack_maps(maps)


def test_projection_on_each_map_is_the_single_maps_shifted_bit_for_bit(maps, stack):
    rng = np.random.default_rng(0)
    for k, m in enumerate(maps):
        b = m.bounds
        n = 3000
        xy = np.stack([rng.uniform(b[0] - 20, b[2] + 20, n), rng.uniform(b[1] - 20, b[3] + 20, n)], axis=1)
        heading = rng.uniform(-np.pi, np.pi, n)
        alone = project(m, xy, heading)
        expected = np.where(alone.lane >= 0, alone.lane + stack.lane_base[k], -1)
        assert (alone.lane >= 0).mean() > 0.1
        for got in (stack.project(xy, heading, np.full(n, k)), project(stack.windows[k], xy, heading)):
            np.testing.assert_array_equal(got.lane, expected)
            for field in ("s", "t", "lane_heading", "distance"):
                np.testing.assert_array_equal(getattr(got, field), getattr(alone, field), err_msg=field)
    # points of different maps in one call
    xy = np.array([[10.0, 0.0], [10.0, 0.0], [10.0, 0.0]])
    mixed = stack.project(xy, np.zeros(3), np.array([0, 1, 2]))
    for k in range(3):
        single = project(maps[k], xy[k : k + 1], np.zeros(1)).lane[0]
        assert mixed.lane[k] == (single + stack.lane_base[k] if single >= 0 else -1)


def test_windows_look_up_their_own_ids_and_lane_data(maps, stack):
    for k, m in enumerate(maps):
        w = stack.windows[k]
        base = int(stack.lane_base[k])
        for lane_id in m.lane_ids[:: max(1, m.num_lanes // 7)]:
            i = m.lane(lane_id)
            assert w.lane(lane_id) == i + base and w.lane_ids[i + base] == lane_id
            np.testing.assert_array_equal(w.lane_polyline(i + base), m.lane_polyline(i))
            np.testing.assert_array_equal(w.successors(i + base), m.successors(i) + base)
            assert w.lane_road[i + base] == m.lane_road[i] + stack.road_base[k]
        assert list(w.own_roads()) == list(range(stack.road_base[k], stack.road_base[k] + len(m.road_ids)))
        np.testing.assert_array_equal(raster_lookup(w)[4], raster_lookup(m)[4])
        assert w.tls_ids == m.tls_ids


def test_routes_missions_flows_and_signals_on_a_window_are_the_maps_own(maps, stack):
    k = NAMES.index("intersection_4way_2lane_signal")
    m, w, base = maps[k], stack.windows[k], int(stack.lane_base[k])
    a, b = m.lane("west_in_0"), m.lane("east_out_0")
    np.testing.assert_array_equal(shortest_route(w, a + base, b + base), np.asarray(shortest_route(m, a, b)) + base)
    spec = make_spec(
        [agent(start_road="west_in", goal={"road": "north_out"})], map_name="intersection_4way_2lane_signal"
    )
    mission = spec.agents[0].mission
    alone, stacked = resolve_mission(m, "a", mission, "m"), resolve_mission(w, "a", mission, "m")
    np.testing.assert_array_equal(stacked.route, alone.route + base)
    np.testing.assert_array_equal(stacked.path_xy, alone.path_xy)
    assert stacked.goal_road == alone.goal_road + stack.road_base[k]
    traffic = TrafficSpec(engine="builtin", density="high")
    flows = density_flows(traffic, m)
    assert flows and [f.route for f in density_flows(traffic, w)] == [f.route for f in flows]
    alone_jt, window_jt = junction_table(m), junction_table(w)  # only the window's own junctions
    assert alone_jt.num_connections > 0
    np.testing.assert_array_equal(window_jt.conn_from, alone_jt.conn_from + base)
    np.testing.assert_array_equal(window_jt.conn_to, alone_jt.conn_to + base)
    np.testing.assert_array_equal(window_jt.zone, alone_jt.zone)
    alone_signals, window_signals = SignalState(m), SignalState(w)
    for t in (0.0, 7.0, 31.0):
        alone_signals.update_fixed_time(t)
        window_signals.update_fixed_time(t)
        np.testing.assert_array_equal(window_signals.via_colour[base : base + m.num_lanes], alone_signals.via_colour)
        assert not window_signals.via_colour[:base].any()


def test_the_combined_map_has_no_space_of_its_own(stack):
    with pytest.raises(TypeError, match="window"):
        project(stack.combined, np.zeros((1, 2)))
    with pytest.raises(ValueError, match="map_index"):
        stack.project(np.zeros((2, 2)), None, np.array([0, 5]))


def test_one_map_is_its_own_stack(maps):
    single = stack_maps(maps[:1])
    assert single.combined is maps[0] and single.windows == [maps[0]]


def test_a_projected_map_pickles_and_projects_the_same_after(maps):
    """The projection's frozen grids are made again on unpickling: maps travel to worker processes."""
    import pickle

    from smarts.core.sim_records import lanes_record

    rng = np.random.default_rng(0)
    xy = rng.uniform(-60.0, 60.0, (200, 2))
    heading = rng.uniform(-np.pi, np.pi, 200)
    before = project(maps[1], xy, heading)
    lanes_record(maps[1])  # a kernel record kept on the map (as after a simulation with leads) stays behind
    copy = pickle.loads(pickle.dumps(maps[1]))
    assert "_lanes_record" not in copy.__dict__ and lanes_record(copy) is not None
    again = project(copy, xy, heading)
    for name in before._fields:
        np.testing.assert_array_equal(getattr(before, name), getattr(again, name))
