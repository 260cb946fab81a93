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
