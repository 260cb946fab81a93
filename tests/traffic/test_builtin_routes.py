"""Built-in traffic: routes are collected first and packed into the flat slot arrays once."""

import numpy as np
import pytest

from smarts.core.spec.traffic import FlowSpec, TrafficSpec
from smarts.maps import load_map
from smarts.scenario import builtin_map_path
from smarts.traffic.builtin import BuiltinTrafficProvider
from smarts.traffic.builtin.routes import RouteTable

ARMS = ("west", "north", "east", "south")


@pytest.fixture(scope="module")
def crossing():
    return load_map(builtin_map_path("intersection_4way_2lane"))


def _all_od_flows():
    return [
        FlowSpec(f"{a}_{b}", origin=f"{a}_in", destination=f"{b}_out", rate=100) for a in ARMS for b in ARMS if a != b
    ] + [FlowSpec(f"{a}_route", route=[f"{a}_in"], rate=100) for a in ARMS]


def test_building_many_routes_packs_the_slot_arrays_once(crossing):
    """Each added route used to repack every slot of all routes before it (quadratic in the
    number of routes); now the arrays are built once, when first read."""
    provider = BuiltinTrafficProvider(TrafficSpec(flows=_all_od_flows()), crossing, 0.1)
    routes = provider.routes
    assert len(routes.routes) == 16
    assert routes.pack_count == 1
    for _ in range(3):  # reads of packed arrays do not repack
        assert routes.slot_int.shape == (5, len(routes._lane))
    assert routes.pack_count == 1


def test_lazy_packing_gives_the_arrays_of_packing_after_every_route(crossing):
    lazy, eager = RouteTable(crossing), RouteTable(crossing)
    pairs = [(a, b) for a in ARMS for b in ARMS if a != b]
    for a, b in pairs:
        lazy.add_roads([f"{a}_in", f"{b}_out"], "route")
        eager.add_roads([f"{a}_in", f"{b}_out"], "route")
        eager.pack()
    np.testing.assert_array_equal(lazy.slot_int, eager.slot_int)
    np.testing.assert_array_equal(lazy.slot_cost, eager.slot_cost)
    assert lazy.pack_count == 1
    # a route added later (a vehicle adopted mid-drive) is in the next read
    before = lazy.slot_int.shape[1]
    lane = crossing.lane("west_in_0")
    route = lazy.add_from_lane(crossing.successors(lane)[0])
    assert lazy.slot_int.shape[1] > before and lazy.pack_count == 2
    assert lazy.slot_int[0, lazy.slot(route, int(crossing.successors(lane)[0]))] == int(crossing.successors(lane)[0])


def test_the_road_tables_of_a_map_are_built_once_per_map_and_each_window_has_its_own():
    """What routing reads of the map alone is built once per map instance (a batch's episodes on
    one map share it), and each window of a map stack has its own map's tables, shifted into the
    stack's lane indices, never another window's or the whole stack's."""
    from smarts.maps.stack import stack_maps

    maps = [load_map(builtin_map_path(n)) for n in ("highway_merge_exit", "t_junction", "intersection_4way_2lane")]
    stack = stack_maps(maps)
    for k, m in enumerate(maps):
        window, base = stack.windows[k], int(stack.lane_base[k])
        alone, first, second = RouteTable(m), RouteTable(window), RouteTable(window)
        assert first._road_lanes is second._road_lanes and first._minor is second._minor
        assert alone._minor and first._minor == {lane + base for lane in alone._minor}
        for road in window.own_roads():
            own = road - int(stack.road_base[k])
            assert first._road_lanes[road] == [lane + base for lane in alone._road_lanes[own]]
            assert first._road_length[road] == alone._road_length[own]


def test_the_episodes_of_a_batch_share_compiled_traffic_but_each_adds_its_own_routes():
    """A simulation of several episodes of one scenario compiles its built-in traffic once: the
    providers share the sources and start from copies of one route table, so a route one of
    them adds (a hand-over) is its own; their missions are resolved once and read-only."""
    from smarts.env.assembly import build_simulation
    from smarts.traffic.builtin import BuiltinTrafficProvider
    from tests.builders import agent, make_spec

    spec = make_spec(
        [agent(start_road="west_in", goal={"road": "east_out"})],
        map_name="intersection_4way_2lane",
        traffic=TrafficSpec(flows=_all_od_flows()),
    )
    sim = build_simulation([spec, spec, spec], seeds=[1, 2, 3])
    providers = [p for own in sim.episode_providers for p in own if isinstance(p, BuiltinTrafficProvider)]
    assert len(providers) == 3 and all(p.sources is providers[0].sources for p in providers)
    assert len({id(p.routes) for p in providers}) == 3 and len({id(p.routes._lane) for p in providers}) == 3
    before = [len(p.routes.routes) for p in providers]
    lane = int(providers[1].map.lane_index_of[providers[1].map.lane_ids[0]])
    providers[1].routes.add_from_lane(lane)
    after = [len(p.routes.routes) for p in providers]
    assert after[1] > before[1] and (after[0], after[2]) == (before[0], before[2])
    alone = BuiltinTrafficProvider(spec.traffic, providers[0].map, 0.1)
    np.testing.assert_array_equal(providers[2].routes.slot_int, alone.routes.slot_int)
    missions = [m for m in sim.missions]
    assert all(m.path_xy is missions[0].path_xy for m in missions) and not missions[0].path_xy.flags.writeable
