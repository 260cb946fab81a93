"""SUMO traffic through libsumo in a real simulation: rows, poses, reactions, seeds, errors.

libsumo holds one SUMO per process, so every test closes its simulation (and with it the
provider) before the next one starts.
"""

from __future__ import annotations

from contextlib import contextmanager

import numpy as np
import pytest

from smarts.core.events import Event
from smarts.core.spec.traffic import FlowSpec, TrafficSpec, TripSpec, VehicleTypeSpec
from smarts.core.vehicle_table import Role, VehicleType
from smarts.env.assembly import build_simulation
from smarts.maps import sumo_net_path
from smarts.scenario import ScenarioError
from smarts.traffic.sumo_provider import SumoTrafficProvider
from tests.builders import agent, make_spec

STOP = np.zeros(3)  # relative target pose: stay where you are


def unchecked(model, *args, **fields):
    """``model`` built without its checks (``model_construct``): a spec the spec models refuse, to
    show the engine's own check names the field too."""
    return model.model_construct(**dict(zip(model.model_fields, args)), **fields)


@contextmanager
def sumo_sim(traffic, agents, map_name, **extra):
    sim = build_simulation(make_spec(agents, map_name=map_name, **extra))
    provider = SumoTrafficProvider(traffic, sim.road_map, sumo_net_path(sim.road_map.source), sim.dt)
    sim.add_provider(provider)
    try:
        yield sim, provider
    finally:
        sim.close()


def _traffic_rows(sim):
    t = sim.table
    return np.flatnonzero(t.alive & (t.role == int(Role.TRAFFIC)))


def _run(sim, steps):
    for _ in range(steps):
        sim.step({"agent_0": STOP})


def test_flows_appear_as_traffic_rows_on_the_road():
    traffic = TrafficSpec(
        engine="sumo",
        vehicle_types={"bus": VehicleTypeSpec("bus", base="bus", length=11.0)},
        flows=[
            FlowSpec("cars", route=["west_in", "east_out"], rate=1800),
            FlowSpec("buses", route=["south_in", "north_out"], rate=900, vehicle_type="bus"),
        ],
    )
    far = agent("north_in", offset=5.0, speed=0.0)
    with sumo_sim(traffic, [far], "intersection_4way_1lane") as (sim, provider):
        sim.reset()
        _run(sim, 60)
        t = sim.table
        rows = _traffic_rows(sim)
        assert len(rows) >= 4
        assert (t.owner[rows] == provider.provider_id).all()
        ids = [t.ids[r] for r in rows]
        assert all(i.startswith(("cars.", "buses.")) for i in ids)
        cars = rows[[i.startswith("cars.") for i in ids]]
        buses = rows[[i.startswith("buses.") for i in ids]]
        assert len(cars) and len(buses)
        assert (t.vtype[cars] == VehicleType.PASSENGER).all() and (t.vtype[buses] == VehicleType.BUS).all()
        assert t.length[cars] == pytest.approx(4.6) and t.width[cars] == pytest.approx(1.9)
        assert t.length[buses] == pytest.approx(11.0) and t.width[buses] == pytest.approx(2.55)
        assert (t.lane[rows] >= 0).all()
        assert (t.lane_distance[rows] < 0.2).all()  # box centres on the lane centre lines
        assert (t.speed[rows] > 1.0).any()


def test_pose_conversion_front_bumper_and_angle():
    """A vehicle on the eastbound road heads ~0 with its centre on the lane centre line; the
    westbound one heads ~pi. ``depart_pos`` is where the box centre starts."""
    traffic = TrafficSpec(
        trips=[
            TripSpec("east", route=["eastbound"], depart_pos=50.0, depart_speed=0.0),
            TripSpec("west", route=["westbound"], depart_pos=80.0, depart_speed=5.0),
        ]
    )
    with sumo_sim(traffic, [agent("eastbound", offset=250.0, speed=0.0)], "straight_2lane_twoway") as (sim, _):
        sim.reset()
        rm, t = sim.road_map, sim.table
        east = t.row_of["east"]
        lane = rm.lane("eastbound_0")
        start = rm.lane_polyline(lane)[0]
        assert t.x[east] == pytest.approx(start[0] + 50.0, abs=0.05)  # inserted, not moved yet
        assert abs(t.y[east] - start[1]) < 0.2
        assert t.heading[east] == pytest.approx(0.0, abs=1e-6)
        _run(sim, 30)
        assert t.heading[east] == pytest.approx(0.0, abs=1e-3)
        assert abs(t.y[east] - start[1]) < 0.2 and t.x[east] > start[0] + 50.0
        assert t.lane[east] == lane and abs(t.t[east]) < 0.2
        west = t.row_of["west"]
        assert abs(abs(t.heading[west]) - np.pi) < 1e-3
        assert t.lane[west] == rm.lane("westbound_0") and abs(t.t[west]) < 0.2
        # kinematics from differences: steady heading, accelerating from standstill
        assert t.yaw_rate[east] == pytest.approx(0.0, abs=1e-6)
        assert t.lat_accel[east] == pytest.approx(0.0, abs=1e-6)


def test_traffic_stops_behind_a_stopped_agent_without_passing_through():
    traffic = TrafficSpec(trips=[TripSpec("follower", route=["eastbound"], depart_pos=10.0, depart_speed=12.0)])
    stopped = agent("eastbound", offset=120.0, speed=0.0)
    with sumo_sim(traffic, [stopped], "straight_2lane_twoway") as (sim, _):
        sim.reset()
        t = sim.table
        me, other = sim.agent_row[0], t.row_of["follower"]
        agent_rear = t.x[me] - t.length[me] / 2
        for _ in range(200):
            sim.step({"agent_0": STOP})
            front = t.x[other] + t.length[other] / 2
            assert front < agent_rear  # never into the agent
            assert not sim.agent_events[0, Event.COLLISION]
        assert t.speed[other] < 0.05
        gap = agent_rear - (t.x[other] + t.length[other] / 2)
        assert 1.0 < gap < 5.0  # stopped close behind it (SUMO's min gap 2.5 m)


@pytest.mark.parametrize("depart_lane", ["best", 0])
def test_sumo_inserts_no_vehicle_onto_an_agent_near_the_road_start(depart_lane):
    """The agent's twin is on its lane before SUMO's first insertion, so a flow starting at the
    road's beginning is not inserted behind (or into) an agent 8 m in at full speed."""
    traffic = TrafficSpec(engine="sumo", flows=[FlowSpec("cars", route=["main"], rate=1800, depart_lane=depart_lane)])
    stopped = agent("main", lane=0, offset=8.0, speed=0.0)
    with sumo_sim(traffic, [stopped], "straight_2lane") as (sim, _):
        sim.reset()
        t = sim.table
        me = sim.agent_row[0]
        agent_rear = t.s[me] - t.length[me] / 2
        for _ in range(20):
            assert not sim.agent_events[0, Event.COLLISION]
            rows = _traffic_rows(sim)
            behind = rows[(t.lane[rows] == t.lane[me]) & (t.s[rows] < t.s[me])]
            # a car behind the agent on its lane has room to stop (SUMO's safe insertion)
            fronts = t.s[behind] + t.length[behind] / 2
            assert (agent_rear - fronts >= 0.5 * t.speed[behind] ** 2 / 4.5 - 1e-6).all()
            sim.step({"agent_0": STOP})
        assert not sim.agent_events[0, Event.COLLISION]


def test_same_seed_same_traffic_other_seed_other_traffic():
    traffic = TrafficSpec(
        flows=[
            FlowSpec(
                "random",
                route=["main"],
                probability=0.3,
                depart_lane="random",
                depart_speed="random",
            ),
        ]
    )
    with sumo_sim(traffic, [agent("main", offset=280.0, speed=0.0)], "straight_2lane") as (sim, _):

        def snapshot(seed):
            sim.reset(seed=seed)
            _run(sim, 80)
            rows = _traffic_rows(sim)
            return {sim.table.ids[r]: (sim.table.x[r], sim.table.y[r], sim.table.speed[r]) for r in rows}

        first = snapshot(1)
        assert len(first) >= 2
        assert snapshot(1) == first
        assert snapshot(2) != first


def test_bad_input_is_raised_at_construction_naming_the_field():
    sim = build_simulation(make_spec([agent()], map_name="straight_2lane"))
    net = sumo_net_path(sim.road_map.source)
    bad = [
        (
            unchecked(TrafficSpec, flows=[unchecked(FlowSpec, "f", route=["main", "side"], rate=10)]),
            r"traffic\.flows\[0\]\.route\[1\]: unknown road 'side'",
        ),
        (
            unchecked(TrafficSpec, trips=[unchecked(TripSpec, "t", route=["main"], vehicle_type="zeppelin")]),
            r"traffic\.trips\[0\]\.vehicle_type: unknown vehicle type",
        ),
    ]
    for traffic, message in bad:
        with pytest.raises(ScenarioError, match=message):
            SumoTrafficProvider(traffic, sim.road_map, net, sim.dt)
    sim.close()


def test_sumo_start_up_failure_is_a_scenario_error_and_sumo_can_start_again():
    sim = build_simulation(make_spec([agent()], map_name="straight_2lane"))
    other_net = sumo_net_path(
        build_simulation(make_spec([agent("eastbound")], map_name="straight_2lane_twoway")).road_map.source
    )
    traffic = TrafficSpec(trips=[TripSpec("t", route=["main"])])
    provider = SumoTrafficProvider(traffic, sim.road_map, other_net, sim.dt)  # has no road 'main'
    sim.add_provider(provider)
    with pytest.raises(ScenarioError, match="SUMO could not start.*'main'"):
        sim.reset()
    sim.close()
    with sumo_sim(traffic, [agent(offset=250.0, speed=0.0)], "straight_2lane") as (sim, _):
        sim.reset()
        assert "t" in sim.table.row_of


def test_malformed_network_is_rejected_before_sumo_sees_it(tmp_path):
    sim = build_simulation(make_spec([agent()], map_name="straight_2lane"))
    broken = tmp_path / "broken.net.xml"
    broken.write_text("<net><edge id='x'></net>")  # SUMO itself would crash on this
    with pytest.raises(ScenarioError, match="broken.net.xml: the SUMO network is not valid XML"):
        SumoTrafficProvider(TrafficSpec(), sim.road_map, broken, sim.dt)
    sim.close()


def test_one_open_provider_per_process():
    with sumo_sim(TrafficSpec(), [agent()], "straight_2lane") as (sim, _):
        sim.reset()
        with pytest.raises(RuntimeError, match="one SUMO simulation per process"):
            SumoTrafficProvider(TrafficSpec(), sim.road_map, sumo_net_path(sim.road_map.source), sim.dt)
    # closed: a new provider may start
    with sumo_sim(TrafficSpec(), [agent()], "straight_2lane") as (sim, _):
        sim.reset()
        _run(sim, 2)


def test_resets_reuse_sumo_and_start_each_episode_afresh():
    traffic = TrafficSpec(trips=[TripSpec("t", route=["main"], depart_pos=20.0, depart_speed=10.0)])
    with sumo_sim(traffic, [agent(offset=280.0, speed=0.0)], "straight_2lane") as (sim, _):
        for _ in range(3):
            sim.reset()
            t = sim.table
            row = t.row_of["t"]
            x0 = t.x[row]
            _run(sim, 10)
            assert x0 + 9.5 < t.x[row] < x0 + 14.0  # 10 m/s and speeding up, for 1 s
            assert sum(1 for r in t.alive_rows if t.role[r] == Role.TRAFFIC) == 1


def test_vehicles_leaving_the_map_lose_their_rows():
    traffic = TrafficSpec(trips=[TripSpec("t", route=["main"], depart_pos=250.0, depart_speed=13.0)])
    with sumo_sim(traffic, [agent(lane=1, offset=20.0, speed=0.0)], "straight_2lane") as (sim, _):
        sim.reset()
        assert "t" in sim.table.row_of
        _run(sim, 60)
        assert "t" not in sim.table.row_of
        assert len(_traffic_rows(sim)) == 0


@pytest.fixture(scope="module")
def long_lanes_net(tmp_path_factory):
    """A 100 m road whose lanes SUMO measures as 120 m (the edge's ``length`` attribute)."""
    from tests.maps.conftest import build_net

    nodes = '<nodes><node id="A" x="0" y="0"/><node id="B" x="100" y="0"/></nodes>'
    edges = '<edges><edge id="AB" from="A" to="B" numLanes="2" speed="20" length="120"/></edges>'
    return build_net(tmp_path_factory.mktemp("long_lanes"), "long_lanes", nodes, edges)


def test_offsets_mean_the_same_place_to_sumo_when_its_lane_length_differs(long_lanes_net):
    """Offsets are metres along the drawn lane for trips and agents alike; SUMO, which counts
    along its 120 m lane length, gets them scaled, so a trip at depart_pos 50 starts in the
    middle of the road and an agent's twin stands where the agent is."""
    from smarts.scenario import read_scenario

    spec = read_scenario(
        {
            "name": "long-lanes",
            "map": str(long_lanes_net),
            "agents": [
                {
                    "action_space": "relative_target_pose",
                    "mission": {
                        "start": {"road": "AB", "lane": 1, "offset": 70.0, "speed": 0.0},
                        "goal": {"endless": True},
                    },
                }
            ],
        },
        source="long-lanes",
    )
    sim = build_simulation(spec)
    rm = sim.road_map
    assert rm.lane_length[0] == pytest.approx(100.0) and rm.lane_sumo_length[0] == pytest.approx(120.0)
    traffic = TrafficSpec(trips=[TripSpec("mid", route=["AB"], depart_pos=50.0, depart_speed=0.0, depart_lane=0)])
    provider = SumoTrafficProvider(traffic, rm, sumo_net_path(rm.source), sim.dt)
    sim.add_provider(provider)
    try:
        sim.reset()
        t = sim.table
        mid = t.row_of["mid"]
        assert t.x[mid] == pytest.approx(50.0, abs=0.05)
        assert t.s[mid] == pytest.approx(50.0, abs=0.05)
        ls = provider._ls
        me = sim.agent_row[0]
        front = t.x[me] + t.length[me] / 2
        assert ls.vehicle.getPosition("agent_0")[0] == pytest.approx(front, abs=0.05)
        # SUMO's own lane position of the twin is the scaled offset
        assert ls.vehicle.getLanePosition("agent_0") == pytest.approx(1.2 * front, abs=0.05)
        sim.step({"agent_0": STOP})
        assert ls.vehicle.getPosition("agent_0")[0] == pytest.approx(front, abs=0.05)
    finally:
        sim.close()
