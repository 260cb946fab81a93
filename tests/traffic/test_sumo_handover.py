"""Hand-over between SUMO and another provider, both ways, on real libsumo."""

from __future__ import annotations

import math

import numpy as np
import pytest

from smarts.core.provider import ProviderBase
from smarts.core.spec.traffic import TrafficSpec, TripSpec
from smarts.core.vehicle_table import Role
from smarts.env.assembly import build_simulation
from smarts.maps import sumo_net_path
from smarts.traffic.sumo_provider import (
    DEFAULT_SPEED_MODE,
    SumoTrafficProvider,
    _libsumo,
)
from tests.builders import agent, make_spec

STOP = {"agent_0": np.zeros(3)}


class Scripted(ProviderBase):
    """Drives its rows straight ahead at a fixed speed; can start with one social vehicle."""

    name = "scripted"

    def __init__(self, start_xy=None, speed=0.0, role=Role.SOCIAL_AGENT):
        self.start_xy, self.speed, self.role = start_xy, speed, role

    def reset(self, sim):
        if self.start_xy is not None:
            sim.table.add(
                "scripted",
                owner=self.provider_id,
                role=self.role,
                x=self.start_xy[0],
                y=self.start_xy[1],
                heading=0.0,
                speed=self.speed,
            )

    def step(self, sim, dt):
        t = sim.table
        rows = t.rows_owned_by(self.provider_id)
        t.speed[rows] = self.speed
        t.x[rows] += self.speed * np.cos(t.heading[rows]) * dt
        t.y[rows] += self.speed * np.sin(t.heading[rows]) * dt

    def can_accept(self, sim, rows):
        return np.ones(len(rows), dtype=bool)

    def accept(self, sim, rows):
        pass


def _sim(traffic, scripted):
    # the learning agent waits out of the way on the westbound road
    sim = build_simulation(make_spec([agent("westbound", offset=20.0, speed=0.0)], map_name="straight_2lane_twoway"))
    sim.add_provider(scripted)  # before SUMO, so SUMO sees this step's poses
    provider = SumoTrafficProvider(traffic, sim.road_map, sumo_net_path(sim.road_map.source), sim.dt)
    sim.add_provider(provider)
    return sim, provider


def test_social_vehicle_is_mirrored_then_handed_to_sumo_which_drives_it():
    rm_lane_y = -1.6  # eastbound lane centre of straight_2lane_twoway
    scripted = Scripted(start_xy=(60.0, rm_lane_y), speed=8.0)
    sim, sumo = _sim(TrafficSpec(), scripted)
    ls = _libsumo()
    try:
        sim.reset()
        for _ in range(10):
            sim.step(STOP)
        t = sim.table
        row = t.row_of["scripted"]
        # the twin in SUMO sits at the row's front bumper, heading east (SUMO angle 90)
        fx, fy = ls.vehicle.getPosition("scripted")
        assert fx == pytest.approx(t.x[row] + t.length[row] / 2, abs=1e-6)
        assert fy == pytest.approx(t.y[row], abs=1e-6)
        assert ls.vehicle.getAngle("scripted") == pytest.approx(90.0, abs=1e-6)
        assert ls.vehicle.getSpeedMode("scripted") == 0

        assert sumo.can_accept(sim, np.array([row])).all()
        sim.hand_over(np.array([row]), sumo, Role.TRAFFIC)
        assert t.owner[row] == sumo.provider_id and t.role[row] == Role.TRAFFIC
        assert ls.vehicle.getSpeedMode("scripted") == DEFAULT_SPEED_MODE
        x0 = t.x[row]
        for _ in range(30):
            sim.step(STOP)
        assert t.alive[row] and t.ids[row] == "scripted"
        assert t.x[row] > x0 + 20.0  # SUMO keeps it going (8 m/s and accelerating)
        assert abs(t.y[row] - rm_lane_y) < 0.2 and abs(t.heading[row]) < 1e-3
        assert ls.vehicle.getRoute("scripted")[-1] == "eastbound"  # the reachable exit
    finally:
        sim.close()


def test_vehicle_sumo_never_saw_is_inserted_at_its_pose_when_handed_over():
    # a replayed vehicle has no twin in SUMO
    scripted = Scripted(start_xy=(100.0, -1.6), speed=6.0, role=Role.REPLAY)
    sim, sumo = _sim(TrafficSpec(), scripted)
    ls = _libsumo()
    try:
        sim.reset()
        sim.step(STOP)
        assert "scripted" not in ls.vehicle.getIDList()
        t = sim.table
        row = t.row_of["scripted"]
        x0 = t.x[row]
        sim.hand_over(np.array([row]), sumo, Role.TRAFFIC)
        sim.step(STOP)
        fx, fy = ls.vehicle.getPosition("scripted")
        assert fx == pytest.approx(x0 + t.length[row] / 2, abs=1.0) and fy == pytest.approx(-1.6, abs=0.2)
        assert t.x[row] == pytest.approx(x0, abs=1.0) and t.speed[row] == pytest.approx(6.0, abs=0.5)
        for _ in range(20):
            sim.step(STOP)
        assert t.x[row] > x0 + 12.0 and t.owner[row] == sumo.provider_id
    finally:
        sim.close()


def test_traffic_vehicle_handed_to_another_provider_stays_in_sumo_as_an_obstacle():
    traffic = TrafficSpec(
        trips=[
            TripSpec("leader", route=["eastbound"], depart_pos=80.0, depart_speed=10.0),
            TripSpec("follower", route=["eastbound"], depart_pos=40.0, depart_speed=10.0),
        ]
    )
    scripted = Scripted(speed=0.0)  # stops whatever it takes over
    sim, _ = _sim(traffic, scripted)
    ls = _libsumo()
    try:
        sim.reset()
        for _ in range(5):
            sim.step(STOP)
        t = sim.table
        leader, follower = t.row_of["leader"], t.row_of["follower"]
        sim.hand_over(np.array([leader]), scripted, Role.SOCIAL_AGENT)
        assert t.owner[leader] == scripted.provider_id
        x_held = t.x[leader]
        for _ in range(150):
            sim.step(STOP)
            assert t.x[follower] + t.length[follower] / 2 < t.x[leader] - t.length[leader] / 2
        assert t.x[leader] == x_held  # only the new owner moves it now
        assert t.speed[follower] < 0.05  # SUMO's follower queued behind the held vehicle
        fx, _ = ls.vehicle.getPosition("leader")
        assert fx == pytest.approx(t.x[leader] + t.length[leader] / 2, abs=1e-6)
        assert ls.vehicle.getSpeedMode("leader") == 0
        assert not math.isnan(t.accel[follower])
    finally:
        sim.close()


def test_agent_twin_follows_its_row_off_the_network_back_and_out_of_the_table():
    scripted = Scripted(start_xy=(60.0, -1.6), speed=5.0)
    sim, _ = _sim(TrafficSpec(), scripted)
    ls = _libsumo()
    try:
        sim.reset()
        sim.step(STOP)
        assert "scripted" in ls.vehicle.getIDList() and "agent_0" in ls.vehicle.getIDList()
        t = sim.table
        row = t.row_of["scripted"]
        assert ls.vehicle.getLaneID("scripted") == "eastbound_0"
        t.y[row] += 200.0  # far off the road network: the twin is off every lane
        sim.step(STOP)
        assert ls.vehicle.getLaneID("scripted") == "" and t.alive[row]
        t.y[row] -= 200.0  # back on its lane
        sim.step(STOP)
        assert ls.vehicle.getLaneID("scripted") == "eastbound_0"
        assert ls.vehicle.getPosition("scripted")[1] == pytest.approx(-1.6, abs=1e-6)
        t.remove(row)
        sim.step(STOP)
        assert "scripted" not in ls.vehicle.getIDList()
    finally:
        sim.close()


def test_agent_takes_over_a_sumo_trip_and_hands_it_back_at_mission_end():
    """``start: {take_over: lead}`` and ``on_end: traffic`` with SUMO as the traffic engine."""
    spec = make_spec(
        [
            {
                "mission": {
                    "start": {"take_over": "lead"},
                    "goal": {"road": "main", "offset": 120.0},
                    "on_end": "traffic",
                }
            }
        ],
        map_name="straight_2lane",
        traffic={
            "engine": "sumo",
            "trips": [
                {
                    "id": "lead",
                    "route": ["main"],
                    "depart_lane": 1,
                    "depart_pos": 40,
                    "depart_speed": 10,
                },
                {
                    "id": "behind",
                    "route": ["main"],
                    "depart_lane": 1,
                    "depart_pos": 10,
                    "depart_speed": 10,
                },
            ],
        },
    )
    sim = build_simulation(spec)  # engine: sumo, so the assembly adds the SUMO provider
    (sumo,) = [p for p in sim.providers if isinstance(p, SumoTrafficProvider)]
    ls = _libsumo()
    try:
        sim.reset()
        t = sim.table
        row = sim.agent_row[0]
        assert t.ids[row] == "lead" and t.owner[row] != sumo.provider_id and t.role[row] == Role.AGENT
        assert ls.vehicle.getSpeedMode("lead") == 0  # SUMO keeps it as the agent's twin
        for _ in range(200):
            sim.step({"agent_0": np.array([1.0, 0.0, 0.0])})  # 10 m/s straight on
            sim.remove_done_agents()
            if not sim.agent_active[0]:
                break
        assert not sim.agent_active[0]
        assert t.owner[row] == sumo.provider_id and t.role[row] == Role.TRAFFIC
        assert ls.vehicle.getSpeedMode("lead") == DEFAULT_SPEED_MODE
        x0 = t.x[row]
        for _ in range(10):
            sim.step({})
        assert t.x[row] > x0 + 8.0  # SUMO drives it on towards the end of the road
    finally:
        sim.close()
