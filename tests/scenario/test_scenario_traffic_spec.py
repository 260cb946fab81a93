"""Traffic section, social agents and vehicle take-over: strict reading, round trip, map checks."""

from __future__ import annotations

import copy
import itertools
from pathlib import Path

import pytest
import yaml

from smarts.scenario import (
    AgentSpec,
    FlowSpec,
    GoalSpec,
    MissionSpec,
    PedestrianFlowSpec,
    ScenarioError,
    StartSpec,
    TrafficSpec,
    TripSpec,
    VehicleTypeSpec,
    check_map,
    list_scenarios,
    load_scenario,
    read_scenario,
    read_scenario_file,
    scenario_to_dict,
    scenario_to_yaml,
)

BASE = {
    "name": "busy",
    "map": "builtin:intersection_4way_2lane",
    "agents": [
        {
            "id": "agent_0",
            "mission": {
                "start": {"road": "south_in", "lane": 0, "offset": 20.0, "speed": 5.0},
                "goal": {"road": "north_out"},
            },
        },
        {
            "id": "agent_1",
            "mission": {
                "start": {"take_over": "lead"},
                "goal": {"road": "east_out", "offset": 50.0},
                "on_end": "traffic",
            },
        },
        {
            "id": "social",
            "policy": "zoo:keep-lane",
            "mission": {"start": {"road": "north_in"}, "goal": {"road": "south_out"}},
        },
    ],
    "traffic": {
        "engine": "sumo",
        "density": "low",
        "vehicle_types": {
            "calm": {"base": "passenger", "max_speed": 25, "accel": 2.0, "tau": 1.5},
            "lorry": {"base": "truck", "length": 9.5, "sigma": 0.0},
        },
        "flows": [
            {"id": "we", "route": ["west_in", "east_out"], "rate": 600, "vehicle_type": "calm"},
            {
                "id": "to_north",
                "origin": "east_in",
                "destination": "north_out",
                "probability": 0.1,
                "begin": 5,
                "end": 100,
                "vehicle_type": "lorry",
                "depart_lane": 1,
                "depart_speed": "max",
                "depart_pos": 3.5,
            },
        ],
        "trips": [
            {
                "id": "lead",
                "route": ["west_in"],
                "depart": 0,
                "depart_lane": 1,
                "depart_pos": 40,
                "depart_speed": 10,
            },
            {"id": "late", "origin": "north_in", "destination": "west_out", "depart": 12.5},
        ],
        "pedestrians": [
            {"id": "crossers", "origin": "south_in", "destination": "north_out", "rate": 300},
        ],
    },
}


class _Delete:
    """Marks a field to remove (its repr names it, so test ids are the same in every process)."""

    def __repr__(self) -> str:
        return "<deleted>"


_DELETE = _Delete()


def _set(data: dict, dotted: str, value) -> dict:
    """Copy of data with one field set, deleted or appended; dotted path with [i] for list items."""
    data = copy.deepcopy(data)
    node = data
    parts = dotted.replace("[", ".").replace("]", "").split(".")
    for part in parts[:-1]:
        node = node[int(part)] if part.isdigit() else node.setdefault(part, {})
    last = int(parts[-1]) if parts[-1].isdigit() else parts[-1]
    if value is _DELETE:
        del node[last]
    elif isinstance(node, list) and last == len(node):
        node.append(value)
    else:
        node[last] = value
    return data


def write_yaml(folder: Path, data, name: str = "busy.yaml") -> Path:
    path = folder / name
    path.write_text(yaml.safe_dump(data), encoding="utf-8")
    return path


# ---------------------------------------------------------------------------- reading
def test_traffic_section_becomes_the_traffic_dataclasses(tmp_path):
    spec = read_scenario_file(write_yaml(tmp_path, BASE))
    expected = TrafficSpec(
        engine="sumo",
        density="low",
        vehicle_types={
            "calm": VehicleTypeSpec("calm", max_speed=25.0, accel=2.0, tau=1.5),
            "lorry": VehicleTypeSpec("lorry", base="truck", length=9.5, sigma=0.0),
        },
        flows=[
            FlowSpec("we", route=["west_in", "east_out"], rate=600.0, vehicle_type="calm"),
            FlowSpec(
                "to_north",
                origin="east_in",
                destination="north_out",
                probability=0.1,
                begin=5.0,
                end=100.0,
                vehicle_type="lorry",
                depart_lane=1,
                depart_speed="max",
                depart_pos=3.5,
            ),
        ],
        trips=[
            TripSpec("lead", route=["west_in"], depart_lane=1, depart_pos=40.0, depart_speed=10.0),
            TripSpec("late", origin="north_in", destination="west_out", depart=12.5),
        ],
        pedestrians=[PedestrianFlowSpec("crossers", "south_in", "north_out", rate=300.0)],
    )
    assert spec.traffic == expected
    assert spec.traffic.flows[1].roads == ["east_in", "north_out"]
    assert spec.traffic.vehicle_type("lorry").length == 9.5
    assert spec.traffic.vehicle_type("bus").base == "bus"  # a default type, never declared
    assert isinstance(spec.traffic.trips[0].depart_speed, float)
    assert isinstance(spec.traffic.flows[1].depart_lane, int)


def test_social_agent_and_take_over_fields(tmp_path):
    spec = read_scenario_file(write_yaml(tmp_path, BASE))
    learner, taker, social = spec.agents
    assert learner.policy is None and not learner.is_social
    assert learner.mission.on_end == "remove" and learner.mission.start.take_over is None
    assert taker.mission.start == StartSpec(take_over="lead")
    assert taker.mission.start.road is None and taker.mission.on_end == "traffic"
    assert social.policy == "zoo:keep-lane" and social.is_social
    assert spec.social_agent_ids == ["social"]


def test_empty_traffic_mapping_gives_the_defaults():
    spec = read_scenario(_set(BASE, "traffic", {}) | {"agents": BASE["agents"][:1]})
    assert spec.traffic == TrafficSpec()
    assert (spec.traffic.engine, spec.traffic.density) == ("builtin", "none")
    plain = read_scenario({**BASE, "agents": BASE["agents"][:1], "traffic": None})
    assert plain.traffic is None


def test_a_declared_type_may_redefine_a_default_name():
    data = _set(BASE, "traffic.vehicle_types.car", {"max_speed": 20})
    assert read_scenario(data).traffic.vehicle_type("car").max_speed == 20.0


def test_dataclass_defaults_keep_older_code_working():
    start = StartSpec("main", 1)
    assert (start.road, start.lane, start.take_over) == ("main", 1, None)
    mission = MissionSpec(start=start, goal=GoalSpec(endless=True))
    assert mission.on_end == "remove"
    assert AgentSpec("a", mission).policy is None


# ---------------------------------------------------------------------------- round trip
def test_dict_and_yaml_round_trip(tmp_path):
    spec = read_scenario_file(write_yaml(tmp_path, BASE))
    as_dict = scenario_to_dict(spec)
    assert read_scenario(as_dict) == spec
    assert read_scenario(yaml.safe_load(scenario_to_yaml(spec))) == spec
    again = read_scenario_file(write_yaml(tmp_path, yaml.safe_load(scenario_to_yaml(spec)), "b.yaml"))
    assert again == spec and scenario_to_dict(again) == as_dict
    assert as_dict["agents"][1]["mission"]["start"] == {"take_over": "lead"}
    assert as_dict["agents"][1]["mission"]["on_end"] == "traffic"
    assert as_dict["agents"][2]["policy"] == "zoo:keep-lane"
    assert "on_end" not in as_dict["agents"][0]["mission"]
    assert "policy" not in as_dict["agents"][0]
    assert "id" not in as_dict["traffic"]["vehicle_types"]["calm"]
    assert "origin" not in as_dict["traffic"]["flows"][0]  # unset fields are left out


@pytest.mark.parametrize("name", list_scenarios())
def test_library_traffic_round_trips_through_yaml(name, library_scenario):
    spec = library_scenario(name)
    assert read_scenario(yaml.safe_load(scenario_to_yaml(spec))) == spec


# ---------------------------------------------------------------------------- invalid input
BAD = [
    # (field to set, value, fragment expected in the message[, dotted path it names when that is
    # not the field set])
    ("traffic", ["flow"], "valid dictionary"),
    ("traffic.engine", "carla", "input should be 'builtin' or 'sumo'"),
    ("traffic.density", "extreme", "'none', 'low', 'medium' or 'high'"),
    ("traffic.rush_hour", True, "unknown field"),
    ("traffic.vehicle_types", ["calm"], "valid dictionary"),
    ("traffic.vehicle_types.calm", 3, "valid dictionary"),
    ("traffic.vehicle_types.calm.base", "tank", "motorcycle"),
    ("traffic.vehicle_types.calm.id", "x", "unknown field"),
    ("traffic.vehicle_types.calm.max_speed", 0, "greater than 0"),
    ("traffic.vehicle_types.calm.tau", -1, "greater than 0"),
    ("traffic.vehicle_types.calm.speed_factor", 0, "greater than 0"),
    ("traffic.vehicle_types.calm.sigma", 1.5, "less than or equal to 1, got 1.5"),
    ("traffic.vehicle_types.calm.sigma", -0.1, "greater than or equal to 0"),
    ("traffic.vehicle_types.calm.min_gap", -1, "greater than or equal to 0"),
    ("traffic.vehicle_types.calm.length", 0, "greater than 0"),
    ("traffic.vehicle_types.calm.politeness", "x", "number"),
    ("traffic.flows", {"we": {}}, "valid list"),
    ("traffic.flows[0]", "west_in", "valid dictionary"),
    ("traffic.flows[0].id", _DELETE, "required field missing"),
    ("traffic.flows[0].id", "", "non-empty string"),
    ("traffic.flows[1].id", "we", "duplicate id 'we'"),
    ("traffic.trips[1].id", "we", "also traffic.flows[0].id"),
    ("traffic.flows[0].speed", 3, "unknown field"),
    ("traffic.flows[0].route", [], "at least 1 item"),
    ("traffic.flows[0].route", "west_in", "valid list"),
    ("traffic.flows[0].route", ["west_in", 3], "valid string", "traffic.flows[0].route[1]"),
    ("traffic.flows[0].origin", "west_in", "not allowed with route"),
    ("traffic.flows[1].destination", _DELETE, "required field missing (a road id)"),
    ("traffic.flows[1].origin", None, "required field missing (a road id)"),  # null: not given
    ("traffic.flows[0].probability", 0.5, "rate (vehicles per hour) or", "traffic.flows[0]"),
    ("traffic.flows[0].rate", _DELETE, "got neither", "traffic.flows[0]"),
    ("traffic.flows[0].rate", 0, "input should be greater than 0, got 0"),
    ("traffic.flows[1].probability", 1.5, "less than or equal to 1"),
    ("traffic.flows[1].probability", 0, "greater than 0"),
    ("traffic.flows[0].begin", -1, "greater than or equal to 0"),
    ("traffic.flows[1].end", 5, "after begin (5 s), got 5"),
    ("traffic.flows[0].begin", 4000, "after begin (4000 s), got 3600", "traffic.flows[0].end"),
    ("traffic.flows[0].vehicle_type", "ufo", "unknown vehicle type 'ufo'"),
    ("traffic.flows[0].depart_lane", "left", "best, random, free, first"),
    ("traffic.flows[0].depart_lane", -1, "integer >= 0"),
    ("traffic.flows[0].depart_lane", 1.0, "lane index"),
    ("traffic.flows[0].depart_lane", True, "lane index"),
    ("traffic.flows[0].depart_speed", "fast", "max, desired, random"),
    ("traffic.flows[0].depart_speed", -2, "a speed in m/s from 0 to 70, got -2"),
    ("traffic.flows[0].depart_pos", -1, "greater than or equal to 0"),
    ("traffic.trips[1].depart", -1, "greater than or equal to 0"),
    ("traffic.trips[1].rate", 5, "unknown field"),
    ("traffic.trips[1].origin", _DELETE, "required field missing"),
    ("traffic.trips[0].route", _DELETE, "route (a list of roads) or origin", "traffic.trips[0]"),
    ("traffic.trips[1].vehicle_type", "tank", "always available: car, bus"),
    ("traffic.trips[1].id", "agent_0", "also the id of agents[0]"),
    ("traffic.pedestrians[0].speed", 0, "greater than 0"),
    ("traffic.pedestrians[0].destination", _DELETE, "missing"),
    ("traffic.pedestrians[0].route", ["a"], "unknown field"),
    ("traffic.pedestrians[0].probability", 0.2, "got both", "traffic.pedestrians[0]"),
    ("traffic.pedestrians[0].end", 0, "after begin"),
    (
        "traffic.pedestrians[1]",
        {"id": "crossers", "origin": "a", "destination": "b", "rate": 1},
        "duplicate id 'crossers' among pedestrian flows",
        "traffic.pedestrians[1].id",
    ),
    ("traffic.engine", "builtin", "pedestrians need engine: sumo", "traffic.pedestrians"),
    ("agents[2].policy", "", "non-empty string"),
    ("agents[2].policy", 7, "valid string"),
    ("agents[2].policy", "zoo:", "zoo locator such as 'zoo:keep-lane'"),
    ("agents[2].policy", "keep lane", "zoo locator"),
    ("agents[1].mission.start.road", "west_in", "not allowed with take_over"),
    ("agents[1].mission.start.speed", 3, "not allowed with take_over"),
    ("agents[1].mission.start.take_over", 3, "valid string"),
    (
        "agents[1].mission.start.take_over",
        "leed",
        "unknown trip 'leed' (did you mean 'lead'?); traffic.trips: lead, late",
    ),
    ("agents[1].mission.start.take_over", "late", "trip 'late' departs at 12.5 s"),
    (
        "agents[2].mission.start",
        {"take_over": "lead"},
        "already taken over by agents[1]",
        "agents[2].mission.start.take_over",
    ),
    ("traffic", _DELETE, "no traffic section", "agents[1].mission.start.take_over"),
    ("agents[1].mission.on_end", "park", "input should be 'remove' or 'traffic'"),
    ("agents[0].mission.start.road", _DELETE, "or give take_over"),
]


@pytest.mark.parametrize("bad", BAD, ids=[f"{b[0]}={b[1]!r}"[:60] for b in BAD])
def test_bad_traffic_and_agent_fields_name_file_and_field(tmp_path, bad):
    dotted, value, fragment = bad[:3]
    path = bad[3] if len(bad) > 3 else dotted
    file = write_yaml(tmp_path, _set(BASE, dotted, value))
    with pytest.raises(ScenarioError) as info:
        read_scenario_file(file)
    message = str(info.value)
    assert message.startswith(f"{file}: {path}: "), message
    assert fragment in message, message


def test_handing_back_to_traffic_needs_a_traffic_section():
    data = _set(BASE, "agents[1].mission.start", {"road": "west_in"})
    data = _set(data, "traffic", _DELETE)
    with pytest.raises(
        ScenarioError,
        match=r"^inline: agents\[1\]\.mission\.on_end: 'traffic' hands the vehicle to traffic, "
        r"but the scenario has no traffic section$",
    ):
        read_scenario(data, source="inline")


def test_flow_needs_a_route_or_both_ends():
    data = _set(BASE, "traffic.flows[1].origin", _DELETE)
    data = _set(data, "traffic.flows[1].destination", _DELETE)
    with pytest.raises(
        ScenarioError,
        match=r"^inline: traffic\.flows\[1\]: expected a route \(a list of roads\) or origin and "
        r"destination, got neither$",
    ):
        read_scenario(data, source="inline")


# ---------------------------------------------------------------------------- check_map
def test_check_map_accepts_valid_traffic(lane_table_maps):
    spec = read_scenario(BASE, source="busy.yaml")
    assert spec.agents[1].mission.start.road is None  # taken over: no start road to check
    check_map(spec, lane_table_maps["intersection_4way_2lane"])


MAP_ERRORS = [
    (
        "traffic.flows[0].route[1]",
        "east_outt",
        (
            "traffic.flows[0].route[1]: map 'intersection_4way_2lane.net.xml' has no road "
            "'east_outt' (did you mean 'east_out'?)"
        ),
    ),
    ("traffic.flows[1].origin", "nowhere", "traffic.flows[1].origin: map "),
    ("traffic.flows[1].destination", "nowhere", "traffic.flows[1].destination: map "),
    (
        "traffic.trips[0].route[0]",
        ":center_0",
        "traffic.trips[0].route[0]: road ':center_0' lies inside a junction",
    ),
    ("traffic.trips[1].destination", "west", "traffic.trips[1].destination: map "),
    (
        "traffic.trips[0].depart_lane",
        2,
        "traffic.trips[0].depart_lane: road 'west_in' has 2 lanes (0..1), got 2",
    ),
    (
        "traffic.flows[1].depart_lane",
        4,
        "traffic.flows[1].depart_lane: road 'east_in' has 2 lanes (0..1), got 4",
    ),
    (
        "traffic.trips[0].depart_pos",
        150,
        ("traffic.trips[0].depart_pos: lane 1 of road 'west_in' is 99.6 m long, got depart_pos 150"),
    ),
    (
        "traffic.flows[0].depart_pos",
        120,
        "traffic.flows[0].depart_pos: road 'west_in' is 99.6 m long, got depart_pos 120",
    ),
    ("traffic.pedestrians[0].origin", "sidewalk", "traffic.pedestrians[0].origin: map "),
    ("traffic.pedestrians[0].destination", "north", "traffic.pedestrians[0].destination: map "),
]


@pytest.mark.parametrize("dotted,value,expected", MAP_ERRORS, ids=[m[0] for m in MAP_ERRORS])
def test_check_map_names_the_traffic_field(lane_table_maps, dotted, value, expected):
    spec = read_scenario(_set(BASE, dotted, value), source="busy.yaml")
    with pytest.raises(ScenarioError) as info:
        check_map(spec, lane_table_maps["intersection_4way_2lane"])
    assert str(info.value).startswith(f"busy.yaml: {expected}"), str(info.value)


def test_check_map_with_the_compiled_map(built_maps, map_cache_dir, library_scenario):
    from smarts.maps import load_map

    spec = library_scenario("straight_takeover")
    road_map = load_map(built_maps["straight_3lane"], cache_dir=map_cache_dir / "maps")
    check_map(spec, road_map)
    data = _set(scenario_to_dict(spec), "traffic.trips[0].depart_lane", 3)
    with pytest.raises(
        ScenarioError,
        match=r"^t\.yaml: traffic\.trips\[0\]\.depart_lane: road 'main' has 3 lanes \(0\.\.2\)",
    ):
        check_map(read_scenario(data, source="t.yaml"), road_map)


# ---------------------------------------------------------------------------- library
TRAFFIC_SCENARIOS = {
    "intersection_4way_signal_traffic": ("builtin", "intersection_4way_2lane_signal"),
    "highway_merge_traffic": ("sumo", "highway_merge_exit"),
    "t_junction_social": ("builtin", "t_junction"),
    "straight_takeover": ("builtin", "straight_3lane"),
    "intersection_pedestrians": ("sumo", "intersection_4way_1lane_peds"),
}


@pytest.mark.parametrize("name", sorted(TRAFFIC_SCENARIOS))
def test_traffic_scenarios_load_with_their_engine_and_map(name, library_scenario):
    spec = library_scenario(name)
    assert (spec.traffic.engine, spec.builtin_map) == TRAFFIC_SCENARIOS[name]
    assert spec.name == name


@pytest.mark.filterwarnings("ignore:Module 'rtree' not available")
def _scenarios_with_routes() -> list[str]:
    """Library scenarios whose traffic names at least one road-to-road step (the others have
    nothing for the route test to check)."""
    names = []
    for name in list_scenarios():
        traffic = load_scenario(name).traffic
        if traffic is not None and any(len(i.roads) > 1 for i in [*traffic.flows, *traffic.trips]):
            names.append(name)
    return names


def test_some_library_scenarios_have_routes_to_check():
    assert len(_scenarios_with_routes()) >= 2


@pytest.mark.parametrize("name", _scenarios_with_routes())
def test_library_traffic_routes_connect(name, sumo_nets, library_scenario):
    """Every flow and trip can drive its roads in order on the map (checked with sumolib)."""
    spec = library_scenario(name)
    net = sumo_nets[spec.builtin_map]
    pairs = [(item.id, a, b) for item in [*spec.traffic.flows, *spec.traffic.trips]
             for a, b in itertools.pairwise(item.roads)]  # fmt: skip
    assert pairs
    for item_id, a, b in pairs:
        assert net.getShortestPath(net.getEdge(a), net.getEdge(b))[0], f"{item_id}: {a}->{b}"


def _direction(net, from_road: str, to_road: str) -> set[str]:
    return {c.getDirection() for c in net.getEdge(from_road).getConnections(net.getEdge(to_road))}


def test_signal_traffic_agent_turns_left_at_a_signal(sumo_nets, library_scenario):
    spec = library_scenario("intersection_4way_signal_traffic")
    net = sumo_nets[spec.builtin_map]
    assert net.getNode("center").getType() == "traffic_light"
    (agent,) = spec.agents
    assert _direction(net, agent.mission.start.road, agent.mission.goal.road) == {"l"}
    assert spec.traffic.density == "medium" and agent.policy is None


def test_merge_traffic_flows_on_the_highway_and_agent_on_the_ramp(library_scenario):
    spec = library_scenario("highway_merge_traffic")
    (agent,) = spec.agents
    assert agent.mission.start.road == "ramp"
    assert spec.traffic.flows and all(f.roads[0] == "main_0" for f in spec.traffic.flows)


def test_social_scenario_has_one_learner_and_one_keep_lane_driver(library_scenario):
    spec = library_scenario("t_junction_social")
    assert [a.policy for a in spec.agents] == [None, "zoo:keep-lane"]
    assert spec.social_agent_ids == ["social_0"]
    assert (spec.traffic.engine, spec.traffic.density) == ("builtin", "low")
    from smarts.core.policies import resolve_policy

    assert resolve_policy("zoo:keep-lane").action_space == "relative_target_pose"  # the locator resolves


def test_takeover_scenario_drives_trip_lead_and_hands_it_back(library_scenario):
    spec = library_scenario("straight_takeover")
    (agent,) = spec.agents
    assert agent.mission.start.take_over == "lead" and agent.mission.on_end == "traffic"
    lead = next(t for t in spec.traffic.trips if t.id == "lead")
    assert (lead.depart, lead.depart_lane, lead.roads) == (0.0, 1, ["main"])


@pytest.mark.filterwarnings("ignore:Module 'rtree' not available")
def test_pedestrian_scenario_agent_goes_straight(sumo_nets, library_scenario):
    spec = library_scenario("intersection_pedestrians")
    net = sumo_nets[spec.builtin_map]
    (agent,) = spec.agents
    assert _direction(net, agent.mission.start.road, agent.mission.goal.road) == {"s"}
    assert len(spec.traffic.pedestrians) >= 1
