"""SUMO route files from traffic specs: vTypes, flows, trips, pedestrians, density, input errors."""

from __future__ import annotations

import xml.etree.ElementTree as ET

import pytest

from smarts.core.spec.traffic import (
    DENSITY_RATES,
    FlowSpec,
    PedestrianFlowSpec,
    TrafficSpec,
    TripSpec,
    VehicleTypeSpec,
)
from smarts.core.vehicle_table import VEHICLE_DIMENSIONS, VehicleType
from smarts.maps import load_map, sumo_net_path
from smarts.scenario import ScenarioError, builtin_map_path
from smarts.traffic.density import density_flows
from smarts.traffic.sumo_routes import AGENT_VTYPE, write_route_file


def unchecked(model, *args, **fields):
    """``model`` built without its checks (``model_construct``): a spec the spec models refuse, to
    show the engine's own check names the field too."""
    return model.model_construct(**dict(zip(model.model_fields, args)), **fields)


def _map(name):
    return load_map(builtin_map_path(name))


def _write(traffic, road_map, tmp_path):
    path = write_route_file(traffic, road_map, tmp_path, seed=3)
    return ET.parse(path).getroot()


def test_vehicle_types_flows_and_trips_are_written_with_sumo_attributes(tmp_path):
    rm = _map("intersection_4way_1lane")
    traffic = TrafficSpec(
        engine="sumo",
        vehicle_types={"calm": VehicleTypeSpec("calm", base="truck", max_speed=20.0, tau=1.8, width=2.4)},
        flows=[
            FlowSpec("late", route=["south_in", "north_out"], probability=0.2, begin=5.0, end=50.0),
            FlowSpec(
                "ew",
                route=["west_in", "east_out"],
                rate=600,
                vehicle_type="calm",
                depart_lane=0,
                depart_speed=8.5,
                depart_pos=20.0,
            ),
        ],
        trips=[TripSpec("solo", origin="north_in", destination="west_out", depart=2.0, depart_speed="max")],
    )
    root = _write(traffic, rm, tmp_path)
    vtypes = {v.get("id"): v.attrib for v in root.iter("vType")}
    assert set(vtypes) == {"car", "calm", AGENT_VTYPE}
    length, _, height, _ = VEHICLE_DIMENSIONS[VehicleType.TRUCK]
    calm = vtypes["calm"]
    assert calm["vClass"] == "truck"
    assert (float(calm["length"]), float(calm["width"]), float(calm["height"])) == (
        length,
        2.4,
        height,
    )
    assert (float(calm["maxSpeed"]), float(calm["tau"])) == (20.0, 1.8)
    for attr in (
        "accel",
        "decel",
        "emergencyDecel",
        "minGap",
        "sigma",
        "speedFactor",
        "speedDev",
        "lcStrategic",
        "lcCooperative",
        "lcSpeedGain",
        "lcKeepRight",
    ):
        assert attr in calm
    flows = {f.get("id"): f.attrib for f in root.iter("flow")}
    assert flows["ew"]["vehsPerHour"] == "600" and "probability" not in flows["ew"]
    assert flows["late"]["probability"] == "0.2" and flows["late"]["begin"] == "5"
    assert (flows["ew"]["from"], flows["ew"]["to"]) == ("west_in", "east_out")
    assert flows["ew"]["departSpeed"] == "8.5" and flows["ew"]["departLane"] == "0"
    # depart_pos is where the box centre starts; SUMO places the front bumper
    assert float(flows["ew"]["departPos"]) == pytest.approx(20.0 + length / 2)
    trip = root.find("trip").attrib
    assert (trip["from"], trip["to"], trip["depart"], trip["departSpeed"]) == (
        "north_in",
        "west_out",
        "2",
        "max",
    )
    # departures in time order, as SUMO reads them
    departs = [float(e.get("begin", e.get("depart"))) for e in root if e.tag in ("flow", "trip")]
    assert departs == sorted(departs)


def test_route_through_several_roads_becomes_from_to_via(tmp_path):
    rm = _map("highway_6lane_ramp")
    root = _write(
        TrafficSpec(flows=[FlowSpec("f", route=["main_0", "main_1", "main_2"], rate=100)]),
        rm,
        tmp_path,
    )
    flow = root.find("flow").attrib
    assert (flow["from"], flow["via"], flow["to"]) == ("main_0", "main_1", "main_2")


def test_lane_index_counts_car_lanes_only_when_roads_have_sidewalks(tmp_path):
    rm = _map("intersection_4way_1lane_peds")
    root = _write(
        TrafficSpec(trips=[TripSpec("t", route=["west_in", "east_out"], depart_lane=0)]),
        rm,
        tmp_path,
    )
    assert root.find("trip").get("departLane") == "1"  # SUMO lane 0 is the sidewalk


def test_pedestrian_flow_walks_between_roads(tmp_path):
    rm = _map("intersection_4way_1lane_peds")
    traffic = TrafficSpec(
        engine="sumo", pedestrians=[PedestrianFlowSpec("p", "south_in", "north_out", rate=120, speed=1.1)]
    )
    root = _write(traffic, rm, tmp_path)
    flow = root.find("personFlow")
    assert flow.get("perHour") == "120"
    assert flow.find("walk").attrib == {"from": "south_in", "to": "north_out", "speed": "1.1"}


def test_density_flows_join_every_entry_to_every_exit_without_u_turns():
    rm = _map("intersection_4way_1lane")
    flows = density_flows(TrafficSpec(density="medium"), rm)
    arms = ("west", "north", "east", "south")
    expected = {f"density.{a}_in.{b}_out" for a in arms for b in arms if a != b}
    assert {f.id for f in flows} == expected
    for f in flows:
        assert f.probability == pytest.approx(DENSITY_RATES["medium"] / 3 / 3600)
        assert f.route == [f.id.split(".")[1], f.id.split(".")[2]]
    highway = {f.id for f in density_flows(TrafficSpec(density="low"), _map("highway_6lane_ramp"))}
    assert highway == {"density.main_0.main_2", "density.ramp.main_2"}
    assert density_flows(TrafficSpec(density="none"), rm) == []


def test_density_level_flows_are_in_the_route_file(tmp_path):
    root = _write(TrafficSpec(density="high"), _map("t_junction"), tmp_path)
    ids = {f.get("id") for f in root.iter("flow")}
    assert "density.west_in.east_out" in ids and "density.south_in.west_out" in ids


@pytest.mark.parametrize(
    "traffic, field",
    [
        (
            unchecked(TrafficSpec, flows=[unchecked(FlowSpec, "f", route=["west_in", "nowhere"], rate=10)]),
            "traffic.flows[0].route[1]",
        ),
        (
            unchecked(TrafficSpec, flows=[unchecked(FlowSpec, "f", origin="nowhere", destination="east_out", rate=10)]),
            "traffic.flows[0].origin",
        ),
        (
            unchecked(
                TrafficSpec, trips=[unchecked(TripSpec, "t", route=["west_in", "east_out"], vehicle_type="hovercraft")]
            ),
            "traffic.trips[0].vehicle_type",
        ),
        (
            unchecked(
                TrafficSpec, flows=[unchecked(FlowSpec, "f", route=["west_in", "east_out"], rate=10, probability=0.1)]
            ),
            "traffic.flows[0]",
        ),
        (
            unchecked(TrafficSpec, flows=[unchecked(FlowSpec, "f", route=["west_in", "east_out"], rate=-5)]),
            "traffic.flows[0].rate",
        ),
        (
            unchecked(TrafficSpec, trips=[unchecked(TripSpec, "t", route=["west_in", "east_out"], depart_lane=3)]),
            "traffic.trips[0].depart_lane",
        ),
        (
            unchecked(TrafficSpec, trips=[unchecked(TripSpec, "t", route=["west_in", "east_out"], depart_pos=500.0)]),
            "traffic.trips[0].depart_pos",
        ),
        (
            unchecked(TrafficSpec, vehicle_types={"x": unchecked(VehicleTypeSpec, "x", base="tank")}),
            "traffic.vehicle_types.x.base",
        ),
        (unchecked(TrafficSpec, density="gridlock"), "traffic.density"),
        (
            unchecked(
                TrafficSpec,
                trips=[
                    unchecked(TripSpec, "a", route=["west_in", "east_out"]),
                    unchecked(TripSpec, "a", route=["west_in", "east_out"]),
                ],
            ),
            "traffic.trips[1].id",
        ),
        (
            unchecked(TrafficSpec, pedestrians=[unchecked(PedestrianFlowSpec, "p", "south_in", "north_out", rate=60)]),
            "traffic.pedestrians[0].origin",
        ),
    ],
)
def test_bad_input_names_the_field(tmp_path, traffic, field):
    rm = _map("intersection_4way_1lane")  # no sidewalks
    with pytest.raises(ScenarioError) as err:
        write_route_file(traffic, rm, tmp_path, seed=0, net_file=sumo_net_path(rm.source))
    assert str(err.value).startswith(field + ":")


def test_route_that_does_not_connect_is_rejected(tmp_path):
    rm = _map("straight_2lane_twoway")  # no U-turn at the ends: eastbound never reaches westbound
    traffic = TrafficSpec(flows=[FlowSpec("f", route=["eastbound", "westbound"], rate=100)])
    with pytest.raises(
        ScenarioError,
        match=r"traffic\.flows\[0\]\.route: road 'eastbound' does not connect to 'westbound'",
    ):
        write_route_file(traffic, rm, tmp_path, seed=0)
    trips = TrafficSpec(trips=[TripSpec("t", origin="westbound", destination="eastbound")])
    with pytest.raises(ScenarioError, match=r"traffic\.trips\[0\]\.destination"):
        write_route_file(trips, rm, tmp_path, seed=0)


def test_pedestrian_map_keeps_the_car_lanes_and_adds_sidewalks_and_crossings():
    peds, plain = _map("intersection_4way_1lane_peds"), _map("intersection_4way_1lane")
    normal = [lane for lane in peds.lane_ids if not lane.startswith(":")]
    assert len(normal) == 8 and all(lane.endswith("_1") for lane in normal)  # sidewalks are _0
    for road in ("west_in", "north_out", "east_in", "south_out"):
        a = peds.lane_polyline(peds.road_lanes(peds.road(road))[0])
        b = plain.lane_polyline(plain.road_lanes(plain.road(road))[0])
        assert a[[0, -1]] == pytest.approx(b[[0, -1]])
    net = ET.parse(sumo_net_path(peds.source)).getroot()
    functions = [e.get("function") for e in net.iter("edge")]
    assert functions.count("crossing") == 4 and functions.count("walkingarea") >= 4
    sidewalks = [
        lane
        for e in net.iter("edge")
        if e.get("function") is None
        for lane in e.iter("lane")
        if lane.get("allow") == "pedestrian"
    ]
    assert len(sidewalks) == 8
