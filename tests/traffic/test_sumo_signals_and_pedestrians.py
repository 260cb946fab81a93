"""SUMO's traffic lights stop its vehicles and feed the SignalState; SUMO persons walk."""

from __future__ import annotations

import numpy as np

from smarts.core.spec.traffic import PedestrianFlowSpec, TrafficSpec, TripSpec
from smarts.core.vehicle_table import Role, VehicleType
from smarts.env.assembly import build_simulation
from smarts.maps import sumo_net_path
from smarts.traffic.signals import GREEN, RED, SignalState
from smarts.traffic.sumo_provider import SumoTrafficProvider
from tests.builders import agent, make_spec

STOP = {"agent_0": np.zeros(3)}


def _sim(traffic, map_name, start_road, signals):
    sim = build_simulation(make_spec([agent(start_road, offset=60.0, speed=0.0)], map_name=map_name))
    state = SignalState(sim.road_map) if signals else None
    provider = SumoTrafficProvider(traffic, sim.road_map, sumo_net_path(sim.road_map.source), sim.dt, state)
    sim.add_provider(provider)
    return sim, provider, state


def test_red_light_queues_traffic_before_the_stop_line_until_green():
    traffic = TrafficSpec(
        trips=[TripSpec("bus_stop", route=["south_in", "north_out"], depart_pos=30.0, depart_speed=10.0)]
    )
    sim, _, signals = _sim(traffic, "intersection_4way_1lane_signal", "west_out", signals=True)
    try:
        sim.reset()
        rm, t = sim.road_map, sim.table
        lane = int(rm.road_lanes(rm.road("south_in"))[0])
        assert signals.lane_colour[lane] == RED  # north-south starts red in netconvert's program
        row = t.row_of["bus_stop"]
        stopped_on_red = False
        for step in range(700):
            sim.step(STOP)
            colour = signals.lane_colour[lane]
            if colour == RED:
                assert t.lane[row] == lane, f"entered the junction on red at step {step}"
                assert t.s[row] + t.length[row] / 2 <= rm.lane_length[lane] + 0.1
                stopped_on_red |= t.speed[row] < 0.1
            if colour == GREEN and t.lane[row] != lane:
                break
        assert stopped_on_red
        assert colour == GREEN and t.lane[row] != lane  # it went once the light turned green
        assert (signals.colour == GREEN).any() and (signals.colour == RED).any()
    finally:
        sim.close()


def test_pedestrians_walk_on_the_sidewalk_as_pedestrian_rows():
    traffic = TrafficSpec(
        engine="sumo", pedestrians=[PedestrianFlowSpec("walkers", "south_in", "north_out", rate=3600)]
    )
    sim, provider, _ = _sim(traffic, "intersection_4way_1lane_peds", "west_in", signals=False)
    try:
        sim.reset()
        for _ in range(60):
            sim.step(STOP)
        t = sim.table
        rows = np.flatnonzero(t.alive & (t.role == int(Role.PEDESTRIAN)))
        assert len(rows) >= 3
        assert all(t.ids[r].startswith("ped:walkers.") for r in rows)
        assert (t.vtype[rows] == VehicleType.PEDESTRIAN).all()
        assert (t.owner[rows] == provider.provider_id).all()
        assert (t.length[rows] == 0.5).all() and (t.width[rows] == 0.5).all()
        first = t.row_of["ped:walkers.0"]
        y0 = t.y[first]
        for _ in range(10):
            sim.step(STOP)
        assert 0.8 < (t.y[first] - y0) < 2.0  # walking north at ~1.3 m/s for 1 s
        assert abs(t.heading[first] - np.pi / 2) < 0.1
        assert 0.8 < t.speed[first] < 1.6
        # on the sidewalk beside the road, not on a car lane
        assert (t.lane_distance[rows] > 2.0).all()
    finally:
        sim.close()
