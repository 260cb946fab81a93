"""The scenario spec: defaults, YAML round trip, strict validation, checks against a real map."""

from __future__ import annotations

import copy
from pathlib import Path

import pytest
import yaml

from smarts.scenario import (
    GoalSpec,
    ScenarioError,
    VehicleSpec,
    check_map,
    list_scenarios,
    map_path,
    read_scenario,
    read_scenario_file,
    scenario_to_dict,
    scenario_to_yaml,
)

BASE = {
    "name": "intersection",
    "map": "builtin:intersection_4way_2lane",
    "agents": [
        {
            "mission": {
                "start": {"road": "west_in", "lane": 1, "offset": 20.0, "speed": 5.0},
                "goal": {"road": "north_out"},
            }
        },
        {
            "action_space": "target_pose",
            "vehicle": {"type": "truck", "length": 8.0},
            "mission": {
                "start": {"road": "east_in"},
                "goal": {"position": [-60.0, 4.8], "radius": 2.5},
                "route_via": ["west_out"],
            },
        },
    ],
}


def write_yaml(folder: Path, data, name: str = "intersection.yaml") -> Path:
    path = folder / name
    path.write_text(yaml.safe_dump(data), encoding="utf-8")
    return path


def test_defaults_are_filled_in(tmp_path):
    spec = read_scenario_file(write_yaml(tmp_path, BASE))
    assert spec.name == "intersection"
    assert (spec.step_length, spec.episode_steps, spec.seed, spec.vehicle_capacity) == (
        0.1,
        1000,
        42,
        256,
    )
    assert spec.agent_ids == ["agent_0", "agent_1"]
    a0, a1 = spec.agents
    assert a0.action_space == "relative_target_pose" and a0.vehicle == VehicleSpec()
    assert a0.mission.goal == GoalSpec(road="north_out") and a0.mission.goal.kind == "road"
    assert a1.mission.goal.kind == "position" and a1.mission.goal.position == (-60.0, 4.8)
    assert a1.mission.start.lane == 0 and a1.mission.start.offset == 0.0
    assert spec.events.terminate_on == ["collision", "off_road", "reached_goal", "max_steps"]
    assert spec.events.not_moving_seconds == 60.0
    assert spec.reward.progress_weight == 1.0 and spec.reward.step_penalty == 0.0
    assert spec.traffic is None and spec.builtin_map == "intersection_4way_2lane"
    dims = a1.vehicle.dimensions()
    assert dims.length == 8.0 and dims.width == 2.5  # override and truck default
    assert a0.vehicle.dimensions().length == 4.6


def test_name_defaults_to_the_file_name(tmp_path):
    data = {k: v for k, v in BASE.items() if k != "name"}
    assert read_scenario_file(write_yaml(tmp_path, data, "my_run.yaml")).name == "my_run"


def test_dict_and_yaml_round_trip(tmp_path):
    data = copy.deepcopy(BASE)
    data["traffic"] = {"flows": [{"id": "we", "route": ["west_in", "east_out"], "rate": 300}]}
    data["events"] = {"terminate_on": ["collision", "wrong_way"], "not_moving_distance": 0.5}
    data["agents"][0]["mission"]["start"]["heading"] = 0.25
    data["agents"][0]["mission"]["goal"] = {"road": "north_out", "lane": 1, "offset": 12.5}
    data["agents"].append({"id": "cruiser", "mission": {"start": {"road": "south_in"}, "goal": {"endless": True}}})
    spec = read_scenario_file(write_yaml(tmp_path, data))
    assert read_scenario(scenario_to_dict(spec)) == spec
    assert read_scenario(yaml.safe_load(scenario_to_yaml(spec))) == spec
    again = read_scenario_file(write_yaml(tmp_path, yaml.safe_load(scenario_to_yaml(spec)), "again.yaml"))
    assert again == spec and scenario_to_dict(again) == scenario_to_dict(spec)
    assert scenario_to_dict(spec)["agents"][2]["mission"]["goal"] == {"endless": True}


@pytest.mark.parametrize("name", list_scenarios())
def test_library_scenarios_round_trip(name, library_scenario):
    spec = library_scenario(name)
    assert read_scenario(scenario_to_dict(spec)) == spec


def _set(data: dict, dotted: str, value) -> dict:
    """Copy of data with one field set; dotted path with [i] for list items."""
    data = copy.deepcopy(data)
    node = data
    parts = dotted.replace("[", ".").replace("]", "").split(".")
    for part in parts[:-1]:
        node = node[int(part)] if part.isdigit() else node.setdefault(part, {})
    last = parts[-1]
    if value is _DELETE:
        del node[last]
    else:
        node[int(last) if last.isdigit() else last] = value
    return data


class _Delete:
    """Marks a field to remove (its repr names it, so test ids are the same in every process)."""

    def __repr__(self) -> str:
        return "<deleted>"


_DELETE = _Delete()

BAD_SPECS = [
    # (field to set, value, dotted path expected in the message, fragment expected)
    ("colour", "red", "colour", "unknown field"),
    ("agents[0].vehicle.colour", "red", "agents[0].vehicle.colour", "unknown field"),
    (
        "agents[1].mission.goal.radius",
        -2,
        "agents[1].mission.goal.radius",
        "input should be greater than 0, got -2",
    ),
    ("agents[1].id", "agent_0", "agents[1].id", "duplicate agent id 'agent_0'"),
    ("agents[0].mission.goal.endless", True, "agents[0].mission.goal", "exactly one goal kind"),
    ("agents[1].mission.goal.road", "west_out", "agents[1].mission.goal", "position and road"),
    ("agents[0].action_space", "joystick", "agents[0].action_space", "relative_target_pose"),
    ("map", "builtin:no_such_map", "map", "unknown built-in map 'no_such_map'"),
    ("map", "roads.osm", "map", ".net.xml"),
    ("map", "missing.net.xml", "map", "does not exist"),
    ("episode_steps", "100", "episode_steps", "input should be a valid integer, got '100'"),
    ("episode_steps", 0, "episode_steps", "input should be greater than or equal to 1, got 0"),
    ("step_length", 2.0, "step_length", "less than or equal to 1"),
    ("seed", 1.5, "seed", "valid integer"),
    ("agents[0].mission.start.lane", 1.5, "agents[0].mission.start.lane", "valid integer"),
    (
        "agents[0].mission.start.speed",
        True,
        "agents[0].mission.start.speed",
        "input should be a valid number, got True",  # strict: true is not a number
    ),
    ("agents[0].mission.start.offset", -1.0, "agents[0].mission.start.offset", "greater than or equal to 0"),
    (
        "agents[0].mission.start.road",
        _DELETE,
        "agents[0].mission.start.road",
        "required field missing (a road id, or give take_over instead)",
    ),
    ("agents[0].mission.goal", _DELETE, "agents[0].mission.goal", "required field missing"),
    (
        "agents[0].mission.goal.radius",
        3.0,
        "agents[0].mission.goal.radius",
        "only allowed with a position goal",
    ),
    (
        "agents[1].mission.goal.position",
        [1.0],
        "agents[1].mission.goal.position",
        "at least 2 items",
    ),
    (
        "agents[1].mission.goal.position",
        [1.0, "a"],
        "agents[1].mission.goal.position[1]",
        "valid number",
    ),
    ("agents[1].vehicle.type", "tank", "agents[1].vehicle.type", "passenger"),
    ("agents[1].vehicle.mass", 0, "agents[1].vehicle.mass", "greater than 0"),
    ("agents[1].mission.route_via", "west_out", "agents[1].mission.route_via", "valid list"),
    ("agents", [], "agents", "at least 1 item"),
    ("agents", _DELETE, "agents", "required field missing"),
    ("vehicle_capacity", 1, "vehicle_capacity", "number of agents (2)"),
    ("events.terminate_on", ["collision", "exploded"], "events.terminate_on[1]", "off_road"),
    ("events.terminate_on", ["collision", "collision"], "events.terminate_on[1]", "listed twice"),
    ("events.not_moving_seconds", 0, "events.not_moving_seconds", "greater than 0"),
    ("reward.goal_bonus", -1, "reward.goal_bonus", "greater than or equal to 0"),
    ("reward.speed_bonus", 1, "reward.speed_bonus", "unknown field"),
    ("traffic", ["flow"], "traffic", "valid dictionary"),
    ("name", "", "name", "non-empty string"),
]


@pytest.mark.parametrize("dotted,value,path,fragment", BAD_SPECS, ids=[f"{b[0]}={b[1]!r}" for b in BAD_SPECS])
def test_bad_spec_names_file_and_field(tmp_path, dotted, value, path, fragment):
    file = write_yaml(tmp_path, _set(BASE, dotted, value))
    with pytest.raises(ScenarioError) as info:
        read_scenario_file(file)
    message = str(info.value)
    assert message.startswith(f"{file}: {path}: "), message
    assert fragment in message, message


def test_error_message_matches_documented_form(tmp_path):
    file = write_yaml(tmp_path, _set(BASE, "agents[1].mission.goal.radius", -2))
    with pytest.raises(
        ValueError,
        match=r"intersection\.yaml: agents\[1\]\.mission\.goal\.radius: "
        r"input should be greater than 0, got -2$",
    ):
        read_scenario_file(file)


def test_unknown_field_suggests_the_close_name(tmp_path):
    file = write_yaml(tmp_path, _set(BASE, "episode_step", 10))
    with pytest.raises(ScenarioError, match="did you mean 'episode_steps'"):
        read_scenario_file(file)


def test_invalid_yaml_and_missing_file_name_the_file(tmp_path):
    bad = tmp_path / "broken.yaml"
    bad.write_text("name: x\nagents: [\n", encoding="utf-8")
    with pytest.raises(ScenarioError, match=r"broken\.yaml: invalid YAML at line \d+"):
        read_scenario_file(bad)
    with pytest.raises(ScenarioError, match=r"absent\.yaml: cannot read"):
        read_scenario_file(tmp_path / "absent.yaml")
    scalar = tmp_path / "scalar.yaml"
    scalar.write_text("42\n", encoding="utf-8")
    with pytest.raises(ScenarioError, match=r"scalar\.yaml: expected a mapping at the top level, got int"):
        read_scenario_file(scalar)
    binary = tmp_path / "binary.yaml"
    binary.write_bytes(b"name: \xff\n")
    with pytest.raises(
        ScenarioError, match=r"binary\.yaml: not a YAML text file \(not UTF-8: byte 0xff at offset 6\)$"
    ):
        read_scenario_file(binary)
    empty = tmp_path / "empty.yaml"
    empty.write_text("", encoding="utf-8")
    with pytest.raises(ScenarioError) as info:  # the name defaults to the file's, as always
        read_scenario_file(empty)
    assert str(info.value) == f"{empty}: map: required field missing\n{empty}: agents: required field missing"


def test_from_dict_names_its_source():
    with pytest.raises(ScenarioError, match=r"^inline: seed: input should be greater than or equal to 0, got -1$"):
        read_scenario(_set(BASE, "seed", -1), source="inline")


def test_map_file_is_resolved_next_to_the_scenario(tmp_path, built_maps):
    folder = tmp_path / "scenarios"
    (folder / "maps").mkdir(parents=True)
    net = folder / "maps" / "cross.net.xml"
    net.write_bytes(built_maps["intersection_4way_2lane"].read_bytes())
    spec = read_scenario_file(write_yaml(folder, _set(BASE, "map", "maps/cross.net.xml")))
    assert spec.builtin_map is None
    assert map_path(spec) == net
    assert scenario_to_dict(spec)["map"] == "maps/cross.net.xml"


def test_builtin_map_path_compiles_the_map(map_cache_dir, built_maps):
    spec = read_scenario(BASE)
    assert map_path(spec, map_cache_dir) == built_maps["intersection_4way_2lane"]


# ---------------------------------------------------------------------------- check_map
def test_check_map_accepts_valid_missions(lane_table_maps):
    spec = read_scenario(BASE, source="intersection.yaml")
    assert check_map(spec, lane_table_maps["intersection_4way_2lane"]) is None
    # The same missions against another map: the check did read the map.
    other = next(m for name, m in lane_table_maps.items() if "west_in" not in name and name.startswith("straight"))
    with pytest.raises(ScenarioError, match="west_in"):
        check_map(spec, other)


MAP_ERRORS = [
    (
        "agents[0].mission.start.lane",
        3,
        "agents[0].mission.start.lane: road 'west_in' has 2 lanes (0..1), got 3",
    ),
    (
        "agents[0].mission.start.road",
        "west_inn",
        "agents[0].mission.start.road: map 'intersection_4way_2lane.net.xml' has no road "
        "'west_inn' (did you mean 'west_in'?)",
    ),
    (
        "agents[0].mission.start.road",
        ":center_0",
        "agents[0].mission.start.road: road ':center_0' lies inside a junction",
    ),
    (
        "agents[0].mission.start.offset",
        150.0,
        "agents[0].mission.start.offset: lane 1 of road 'west_in' is 99.6 m long, got offset 150",
    ),
    (
        "agents[0].mission.goal.lane",
        2,
        "agents[0].mission.goal.lane: road 'north_out' has 2 lanes (0..1), got 2",
    ),
    (
        "agents[0].mission.goal.offset",
        120.0,
        "agents[0].mission.goal.offset: road 'north_out' is 99.6 m long",
    ),
    (
        "agents[1].mission.route_via",
        ["nowhere"],
        "agents[1].mission.route_via[0]: map 'intersection_4way_2lane.net.xml' has no road 'nowhere'",
    ),
    (
        "agents[1].mission.goal.position",
        [500.0, 0.0],
        "agents[1].mission.goal.position: (500, 0) lies outside the map bounds",
    ),
]


@pytest.mark.parametrize("dotted,value,expected", MAP_ERRORS, ids=[m[0] for m in MAP_ERRORS])
def test_check_map_names_agent_and_field(lane_table_maps, dotted, value, expected):
    spec = read_scenario(_set(BASE, dotted, value), source="intersection.yaml")
    with pytest.raises(ScenarioError) as info:
        check_map(spec, lane_table_maps["intersection_4way_2lane"])
    assert str(info.value).startswith(f"intersection.yaml: {expected}"), str(info.value)


def test_check_map_with_the_map_compiler(built_maps, map_cache_dir):
    """The spec checked against the map the real compiler builds."""
    from smarts import maps

    road_map = maps.load_map(built_maps["intersection_4way_2lane"], cache_dir=map_cache_dir / "maps")
    spec = read_scenario(BASE, source="intersection.yaml")
    check_map(spec, road_map)
    with pytest.raises(ScenarioError, match=r"agents\[0\]\.mission\.start\.lane: road 'west_in' has 2 lanes"):
        check_map(read_scenario(_set(BASE, "agents[0].mission.start.lane", 3)), road_map)


# ---------------------------------------------------------------------------- the schema
def test_every_problem_is_reported_at_once_each_with_file_and_field(tmp_path):
    data = _set(BASE, "seed", -1)
    data = _set(data, "agents[0].mission.goal.raod", "north_out")
    data = _set(data, "agents[1].vehicle.mass", 0)
    data = _set(data, "events.terminate_on", ["collision", "exploded"])
    file = write_yaml(tmp_path, data)
    with pytest.raises(ScenarioError) as info:
        read_scenario_file(file)
    lines = str(info.value).splitlines()
    assert [line.split(": ")[1] for line in lines] == [
        "seed",
        "agents[0].mission.goal.raod",
        "agents[1].vehicle.mass",
        "events.terminate_on[1]",
    ]
    assert all(line.startswith(f"{file}: ") for line in lines)


@pytest.mark.parametrize(
    "dotted,expected",
    [
        ("agents[0].mission.goal.raod", "agents[0].mission.goal.raod: unknown field; did you mean 'road'?"),
        ("agents[1].mission.start.ofset", "agents[1].mission.start.ofset: unknown field; did you mean 'offset'?"),
        ("agents[0].interface.lidar.rayz", "agents[0].interface.lidar.rayz: unknown field; did you mean 'rays'?"),
        (
            "traffic.vehicle_types.calm.max_sped",
            "traffic.vehicle_types.calm.max_sped: unknown field; did you mean 'max_speed'?",
        ),
        ("traffic.flows[0].vehicle_typ", "traffic.flows[0].vehicle_typ: unknown field; did you mean 'vehicle_type'?"),
        ("comms.latncy", "comms.latncy: unknown field; did you mean 'latency'?"),
    ],
)
def test_a_misspelt_key_at_a_nested_path_gets_a_did_you_mean(dotted, expected):
    data = _set(
        BASE, "traffic", {"vehicle_types": {"calm": {}}, "flows": [{"id": "f", "route": ["west_in"], "rate": 60}]}
    )
    data = _set(data, "agents[0].interface", {"lidar": {}})
    data = _set(data, "comms", {})
    with pytest.raises(ScenarioError) as info:
        read_scenario(_set(data, dotted, 1), source="inline")
    assert str(info.value).startswith(f"inline: {expected} (known: "), str(info.value)


@pytest.mark.parametrize(
    "dotted,value,expected",
    [
        ("step_length", True, "step_length: input should be a valid number, got True"),
        (
            "agents[0].mission.start.offset",
            False,
            "agents[0].mission.start.offset: input should be a valid number, got False",
        ),
        ("seed", True, "seed: input should be a valid integer, got True"),
        ("agents[0].mission.start.lane", "1", "agents[0].mission.start.lane: input should be a valid integer, got '1'"),
        ("reward.goal_bonus", "10", "reward.goal_bonus: input should be a valid number, got '10'"),
        ("agents[0].mission.goal.endless", 1, "agents[0].mission.goal.endless: input should be a valid boolean, got 1"),
        ("name", 7, "name: input should be a valid string, got 7"),
    ],
)
def test_types_are_strict(dotted, value, expected):
    """true is not a number and "1" is not an integer (an integer is a valid number)."""
    with pytest.raises(ScenarioError) as info:
        read_scenario(_set(BASE, dotted, value), source="inline")
    assert str(info.value) == f"inline: {expected}"


def test_integers_are_read_as_floats_where_numbers_are_expected():
    spec = read_scenario(_set(BASE, "agents[0].mission.start.offset", 20), source="inline")
    assert type(spec.agents[0].mission.start.offset) is float and spec.agents[0].mission.start.offset == 20.0
    assert type(spec.agents[1].mission.goal.position[0]) is float


def test_each_section_is_one_frozen_strict_model_read_and_built_alike():
    """A section's file layout and what the simulator reads are the same class: closed, strict and
    frozen, checking values built in code by the rules a file is read with."""
    import smarts.core.spec as core_spec
    from smarts.core.spec import Spec

    models = [getattr(core_spec, name) for name in core_spec.__all__]
    models = [m for m in models if isinstance(m, type) and issubclass(m, Spec) and m is not Spec]
    assert len(models) == 22
    for model in models:
        config = model.model_config
        assert (config["extra"], config["strict"], config["frozen"]) == ("forbid", True, True), model.__name__
    with pytest.raises(ScenarioError, match=r"FlowSpec: <top>: expected exactly one of rate"):
        core_spec.FlowSpec(id="f", route=["a"])
    with pytest.raises(ScenarioError, match=r"GoalSpec: radius: only allowed with a position goal"):
        core_spec.GoalSpec(road="r", radius=2.0)
    assert core_spec.GoalSpec(position=[1, 2]).position == (1.0, 2.0)
