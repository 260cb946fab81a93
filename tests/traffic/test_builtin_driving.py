"""Built-in traffic: car following (IDM), reacting to agents, lane changes (MOBIL and route)."""

import numpy as np
import pytest

from smarts.core.spec.traffic import FlowSpec, TrafficSpec, TripSpec, VehicleTypeSpec
from tests.traffic.builtin_support import step, traffic_rows, traffic_sim

STEADY = {"speed_dev": 0.0}  # every vehicle drives at exactly its type's desired speed


def _bumper_gap(sim, follower: str, leader: str) -> float:
    t = sim.table
    a, b = t.row_of[follower], t.row_of[leader]
    return float(np.hypot(t.x[b] - t.x[a], t.y[b] - t.y[a]) - 0.5 * (t.length[a] + t.length[b]))


def test_follower_converges_to_the_leader_speed_at_a_safe_gap():
    types = {"slow": VehicleTypeSpec("slow", max_speed=6.0, **STEADY), "fast": VehicleTypeSpec("fast", **STEADY)}
    trips = [
        TripSpec("leader", route=["eastbound"], depart_pos=60.0, vehicle_type="slow"),
        TripSpec("follower", route=["eastbound"], vehicle_type="fast"),
    ]
    sim, _ = traffic_sim("straight_2lane_twoway", TrafficSpec(vehicle_types=types, trips=trips), "westbound")
    gaps = []
    for _ in range(300):
        step(sim)
        gaps.append(_bumper_gap(sim, "follower", "leader"))
    t = sim.table
    v_follower = t.speed[t.row_of["follower"]]
    assert min(gaps) > 2.0  # never closer than about the standstill gap
    assert v_follower == pytest.approx(6.0, abs=0.3)
    # IDM equilibrium: (s0 + v T) / sqrt(1 - (v / v0)^4) with v0 = the lane's 13.89 m/s
    expected = (2.5 + 6.0 * 1.0) / np.sqrt(1.0 - (6.0 / 13.89) ** 4)
    assert gaps[-1] == pytest.approx(expected, abs=1.0)


def test_traffic_stops_behind_an_agent_standing_on_its_lane():
    trip = TripSpec("car", route=["eastbound"], depart_speed=13.0)
    sim, _ = traffic_sim(
        "straight_2lane_twoway", TrafficSpec(trips=[trip]), "eastbound", keep_agent=True, offset=120.0, speed=0.0
    )
    agent_row = sim.agent_row[0]
    gaps = []
    for _ in range(250):
        step(sim)
        gaps.append(_bumper_gap(sim, "car", sim.table.ids[agent_row]))
    car = sim.table.row_of["car"]
    assert sim.table.speed[car] < 0.05
    assert 1.0 < gaps[-1] < 4.0 and min(gaps) > 1.0
    assert sim.table.x[agent_row] == pytest.approx(120.0, abs=1e-6)  # the agent was not pushed


def test_faster_vehicle_changes_lane_to_pass_a_slow_one():
    types = {"slow": VehicleTypeSpec("slow", max_speed=5.0, **STEADY), "fast": VehicleTypeSpec("fast", **STEADY)}
    trips = [
        TripSpec("slow", route=["main"], depart_pos=50.0, depart_lane=0, vehicle_type="slow"),
        TripSpec("fast", route=["main"], depart_lane=0, vehicle_type="fast"),
    ]
    sim, _ = traffic_sim("straight_2lane", TrafficSpec(vehicle_types=types, trips=trips), "main", lane=1, offset=295.0)
    lanes, passed = set(), False
    for _ in range(250):
        step(sim)
        t = sim.table
        if "fast" not in t.row_of:
            break
        fast, slow = t.row_of["fast"], t.row_of["slow"]
        lanes.add(sim.road_map.lane_ids[t.lane[fast]])
        passed |= t.x[fast] > t.x[slow] + 5.0
    assert "main_1" in lanes and passed


def test_vehicles_bound_for_the_exit_change_lanes_to_reach_it():
    flow = FlowSpec("out", origin="main_0", destination="exit", rate=900, depart_lane=2)
    sim, provider = traffic_sim("highway_merge_exit", TrafficSpec(flows=[flow]), "main_4")
    last_lane = {}
    for _ in range(900):
        step(sim)
        for row in traffic_rows(provider):
            last_lane[sim.table.ids[row]] = sim.road_map.lane_ids[sim.table.lane[row]]
    gone = [vid for vid in last_lane if vid not in sim.table.row_of]
    assert len(gone) >= 10
    assert all(last_lane[vid] == "exit_0" for vid in gone)


def test_ramp_vehicles_merge_onto_the_highway():
    flows = [
        FlowSpec("main", route=["main_0", "main_4"], rate=1800, depart_lane="random"),
        FlowSpec("ramp", route=["ramp", "main_4"], rate=600),
    ]
    sim, provider = traffic_sim("highway_merge_exit", TrafficSpec(flows=flows), "exit")
    for _ in range(900):
        step(sim)
    ramp_departed = provider.count[1]
    ramp_left = sum(1 for n in range(ramp_departed) if f"ramp.{n}" not in sim.table.row_of)
    assert ramp_departed >= 12 and ramp_left >= ramp_departed - 6
