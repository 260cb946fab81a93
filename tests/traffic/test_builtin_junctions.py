"""Built-in traffic at junctions: signals, right of way, merges; no two vehicles ever overlap."""

import numpy as np
import pytest

from smarts.core.spec.traffic import FlowSpec, TrafficSpec, TripSpec
from smarts.traffic.signals import RED
from tests.traffic.builtin_support import (
    front_to_lane_end,
    overlapping,
    step,
    traffic_rows,
    traffic_sim,
)

SOUTH_TO_NORTH_LINK = 9  # intersection_4way_1lane_signal: red for 45 s from t = 0, then green


def test_red_light_stops_traffic_before_the_stop_line_and_green_releases_it():
    trip = TripSpec("car", route=["south_in", "north_out"], depart_pos=10.0)
    sim, provider = traffic_sim("intersection_4way_1lane_signal", TrafficSpec(trips=[trip]), "west_in", signals=True)
    signals = provider.signals
    link = int(np.flatnonzero(signals.link == SOUTH_TO_NORTH_LINK)[0])
    south_in = sim.road_map.lane("south_in_0")
    waited_at_line, crossed_at = False, None
    for _ in range(700):
        step(sim)
        if "car" not in sim.table.row_of:
            break
        row = sim.table.row_of["car"]
        red = signals.colour[link] == RED
        if sim.table.lane[row] == south_in:
            gap = front_to_lane_end(sim, row)
            assert gap > 0.0 or not red  # never over the line at red
            waited_at_line |= red and sim.table.speed[row] < 0.05 and gap < 5.0
        elif crossed_at is None:
            crossed_at = sim.time
            assert not red
    assert waited_at_line
    assert crossed_at is not None and 45.0 <= crossed_at < 60.0


def _side_road_entry(with_main: bool):
    """(time the side-road car enters the junction, x of the main-road car then)."""
    trips = [TripSpec("side", route=["south_in", "west_out"], depart_pos=40.0)]
    if with_main:
        trips.append(TripSpec("main", route=["west_in", "east_out"], depart_pos=20.0))
    sim, _ = traffic_sim("t_junction", TrafficSpec(trips=trips), "east_in")
    for _ in range(300):
        step(sim)
        t = sim.table
        side = t.row_of["side"]
        if with_main:
            assert not overlapping(sim, np.array([side, t.row_of["main"]])).any()
        if sim.road_map.lane_internal[t.lane[side]]:
            return sim.time, (t.x[t.row_of["main"]] if with_main else None)
    raise AssertionError("the side-road car never entered the junction")


def test_side_road_vehicle_waits_for_the_main_road_vehicle():
    # The side-road car turns left across the main road, where a car going straight would reach
    # the junction at about the same time: it lets that car pass first.
    alone, _ = _side_road_entry(with_main=False)
    entered, main_x = _side_road_entry(with_main=True)
    assert entered > alone + 1.0
    # The main car (4.6 m long) had cleared the side car's path (x of about -1.6 .. 1.6).
    assert main_x > 1.6 + 2.3 + 2.0


def _assert_no_overlap(sim, provider, steps):
    most = 0
    for _ in range(steps):
        step(sim)
        rows = traffic_rows(provider)
        most = max(most, len(rows))
        if len(rows) > 1:
            hit = overlapping(sim, rows)
            assert not hit.any(), [sim.table.ids[r] for r in rows[hit]]
    return most


def test_merging_and_weaving_traffic_never_overlaps():
    flows = [
        FlowSpec("through", route=["main_0", "main_4"], rate=2400, depart_lane="random"),
        FlowSpec("leaving", origin="main_0", destination="exit", rate=600, depart_lane="random"),
        FlowSpec("joining", route=["ramp", "main_4"], rate=900),
    ]
    sim, provider = traffic_sim("highway_merge_exit", TrafficSpec(flows=flows), "exit", capacity=300)
    assert _assert_no_overlap(sim, provider, 1500) > 40
    joined = sum(1 for n in range(provider.count[2]) if f"joining.{n}" not in sim.table.row_of)
    assert joined > 20  # the ramp traffic got onto the highway and through


@pytest.mark.parametrize("map_name", ["t_junction", "intersection_4way_1lane", "intersection_4way_2lane_signal"])
def test_dense_junction_traffic_never_overlaps(map_name):
    sim, provider = traffic_sim(
        map_name, TrafficSpec(density="high"), "west_out", signals=map_name.endswith("signal"), capacity=300
    )
    assert _assert_no_overlap(sim, provider, 1200) > 25
    assert provider.count.sum() - provider.mine.sum() > 30  # vehicles went through and left
