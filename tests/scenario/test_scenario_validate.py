"""``smarts scenario validate`` and the checks it makes: the schema's physical bounds, missions and
traffic routes on the real compiled map, every problem at once naming file and field, exit codes,
and no traceback for any bad input. Every built-in scenario and benchmark suite stays valid."""

from __future__ import annotations

import copy
import subprocess
import sys
from pathlib import Path

import pytest
import yaml

from smarts.__main__ import main
from smarts.core.spec.scenario import ACTION_SPACES
from smarts.scenario import ScenarioError, list_scenarios, read_scenario
from smarts.scenario.map_check import START_SPEED_MARGIN
from smarts.scenario.validate import validate_scenario, validate_spec
from tests.builders import with_

ROOT = Path(__file__).resolve().parents[2]

TWO_WAY = {
    "name": "two_way",
    "map": "builtin:straight_2lane_twoway",
    "agents": [
        {"mission": {"start": {"road": "eastbound", "offset": 10}, "goal": {"road": "eastbound", "offset": 200}}}
    ],
}
"""A 300 m two-way road: 'eastbound' and 'westbound', one lane each, no way to turn around."""

CROSS = {
    "name": "cross",
    "map": "builtin:intersection_4way_1lane",
    "agents": [{"mission": {"start": {"road": "west_in", "offset": 20, "speed": 8}, "goal": {"road": "north_out"}}}],
}


@pytest.fixture(autouse=True)
def _private_cache(monkeypatch, map_cache_dir):
    monkeypatch.setenv("SMARTS_CACHE_DIR", str(map_cache_dir))


def write(folder: Path, data, name: str = "scenario.yaml") -> Path:
    path = folder / name
    path.write_text(data if isinstance(data, str) else yaml.safe_dump(data), encoding="utf-8")
    return path


def validate_cli(capsys, *files) -> tuple[int, list[str], str]:
    code = main(["scenario", "validate", *map(str, files)])
    captured = capsys.readouterr()
    return code, captured.out.splitlines(), captured.err


# ---------------------------------------------------------------------------- missions on the map
def test_an_unreachable_goal_is_reported_naming_the_field(tmp_path, capsys):
    file = write(tmp_path, with_(TWO_WAY, agents__0__mission__goal={"road": "westbound"}))
    code, out, _ = validate_cli(capsys, file)
    assert code == 2
    assert out == [f"{file}: agents[0].mission.goal: no route from road 'eastbound' lane 0 to road 'westbound'"]


def test_show_build_makes_the_same_checks(tmp_path, capsys):
    file = write(tmp_path, with_(TWO_WAY, agents__0__mission__goal={"road": "westbound"}))
    assert main(["scenario", "show", str(file), "--build"]) == 2  # as validate: one code for one kind of error
    captured = capsys.readouterr()
    assert "# roads: 2 (+0 inside junctions), lanes: 2" in captured.out
    assert (
        captured.err
        == f"error: {file}: agents[0].mission.goal: no route from road 'eastbound' lane 0 to road 'westbound'\n"
    )


def test_a_valid_scenario_exits_0(tmp_path, capsys):
    file = write(tmp_path, TWO_WAY)
    code, out, _ = validate_cli(capsys, file)
    assert code == 0
    assert out == [
        f"{file}: valid (1 agent; map builtin:straight_2lane_twoway: roads: 2 (+0 inside junctions), lanes: 2)"
    ]


def test_every_problem_of_every_file_is_reported(tmp_path, capsys):
    data = copy.deepcopy(CROSS)
    data["agents"] += [
        # a goal past a dead end (every *_out road ends at the map's edge), a via road no route
        # enters (every *_in road starts there), a start too fast and a goal offset past the road
        {"mission": {"start": {"road": "west_out"}, "goal": {"road": "east_out", "lane": 0}}},
        {"mission": {"start": {"road": "south_in"}, "goal": {"endless": True}, "route_via": ["west_in"]}},
        {"mission": {"start": {"road": "west_in", "speed": 40}, "goal": {"road": "east_out", "offset": 500}}},
    ]
    data["traffic"] = {
        "flows": [{"id": "f", "route": ["west_in", "north_out", "east_in"], "rate": 600}],
        "trips": [{"id": "t", "origin": "north_out", "destination": "south_in"}],
    }
    bad = write(tmp_path, data, "bad.yaml")
    good = write(tmp_path, CROSS, "good.yaml")
    code, out, err = validate_cli(capsys, good, bad)
    assert code == 2
    limit = 13.89
    assert out == [
        f"{good}: valid (1 agent; map builtin:intersection_4way_1lane: roads: 8 (+20 inside junctions), lanes: 28)",
        f"{bad}: agents[1].mission.goal: no route from road 'west_out' lane 0 to road 'east_out' lane 0",
        f"{bad}: agents[2].mission.route_via[0]: no route from road 'south_in' lane 0 to road 'west_in'",
        f"{bad}: agents[3].mission.start.speed: lane 0 of road 'west_in' has a speed limit of {limit:.2f} m/s; "
        f"expected at most 1.5 times that ({limit * START_SPEED_MARGIN:.2f} m/s), got 40",
        f"{bad}: agents[3].mission.start.speed: the relative_target_pose action space drives at most 22.22 m/s "
        "(ReachLimits.max_speed), got 40",
        f"{bad}: agents[3].mission.goal.offset: road 'east_out' is 102.8 m long, got offset 500",
        f"{bad}: traffic.flows[0].route[2]: no route from road 'north_out' to road 'east_in'",
        f"{bad}: traffic.trips[0].destination: no route from road 'north_out' to road 'south_in'",
    ]
    assert err == "1 of 2 scenarios valid\n"


def test_a_goal_position_no_route_reaches(tmp_path, capsys):
    # (150, 1.6) lies on westbound (the eastbound lane runs along y = -1.6): no lane leads there.
    file = write(tmp_path, with_(TWO_WAY, agents__0__mission__goal={"position": [150.0, 1.6]}))
    code, out, _ = validate_cli(capsys, file)
    assert code == 2 and len(out) == 1
    assert out[0].startswith(
        f"{file}: agents[0].mission.goal: no route from road 'eastbound' lane 0 to the goal position (150, 1.6) on road 'westbound' lane 0"
    ), out


def test_the_reach_limits_bound_only_the_spaces_that_obey_them():
    data = with_(
        {"name": "fast", "map": "builtin:highway_merge_exit", "agents": []},
        agents=[
            {
                "action_space": space,
                "mission": {"start": {"road": "main_0", "offset": 10, "speed": 30}, "goal": {"endless": True}},
            }
            for space in ACTION_SPACES
        ],
    )  # main_0 allows 25 m/s: 30 is within its limit times 1.5, above the pose spaces' 22.22
    result = validate_spec(read_scenario(data, source="fast"))
    assert [line.split(": ")[1] for line in result.problems] == [
        f"agents[{i}].mission.start.speed" for i, space in enumerate(ACTION_SPACES) if space != "continuous"
    ]


def test_the_simulation_refuses_what_validate_reports(tmp_path):
    from smarts.env.parallel_env import DrivingParallelEnv

    file = write(tmp_path, with_(TWO_WAY, agents__0__mission__goal={"road": "westbound"}))
    with pytest.raises(
        ScenarioError, match=r"agents\[0\]\.mission\.goal: no route from road 'eastbound' lane 0 to road 'westbound'"
    ):
        DrivingParallelEnv(str(file))


# ---------------------------------------------------------------------------- bad input, no traceback
NOT_A_NETWORK = '<net version="1.9"><edge id="a"></net>'
REJECTED_BY_NETCONVERT = '<OpenDRIVE><road id="1" length="-5"><planView><geometry/></planView></road></OpenDRIVE>'


def _bad_inputs(folder: Path) -> dict[str, tuple[Path, str]]:
    """name -> (file, the start of the problem expected after ``file: ``)."""
    agents = "agents:\n  - mission: {start: {road: a}, goal: {endless: true}}\n"
    (folder / "broken.net.xml").write_text(NOT_A_NETWORK, encoding="utf-8")
    (folder / "rejected.xodr").write_text(REJECTED_BY_NETCONVERT, encoding="utf-8")
    (folder / "directory.yaml").mkdir()
    (folder / "binary.yaml").write_bytes(b"\xff\xfe\x00\x01")
    return {
        "bad YAML": (write(folder, "map: [\n", "yaml.yaml"), "invalid YAML at line 2"),
        "missing map file": (write(folder, "map: absent.net.xml\n" + agents, "no_map.yaml"), "map: map file "),
        "malformed network": (write(folder, "map: broken.net.xml\n" + agents, "broken.yaml"), "map: "),
        "netconvert rejects": (
            write(folder, "map: rejected.xodr\n" + agents, "rejected.yaml"),
            "map: " + str(folder / "rejected.xodr") + ": netconvert could not convert",
        ),
        "not UTF-8": (folder / "binary.yaml", "not a YAML text file (not UTF-8"),
        "a folder": (folder / "directory.yaml", "cannot read scenario file"),
        "no file": (folder / "absent.yaml", "cannot read scenario file"),
        "empty": (write(folder, "", "empty.yaml"), "map: required field missing"),
        "a list": (write(folder, "- 1\n", "list.yaml"), "expected a mapping at the top level"),
        "unknown road": (
            write(folder, "map: builtin:straight_2lane\n" + agents, "road.yaml"),
            "agents[0].mission.start.road: ",
        ),
    }


def test_bad_input_is_a_problem_line_never_a_traceback(tmp_path, capsys):
    cases = _bad_inputs(tmp_path)
    for name, (file, expected) in cases.items():
        code, out, err = validate_cli(capsys, file)
        assert code == 2, name
        assert out and out[0].startswith(f"{file}: {expected}"), (name, out)
        assert "Traceback" not in "\n".join(out) + err and "internal error" not in "\n".join(out), name
    result = subprocess.run(
        [sys.executable, "-m", "smarts", "scenario", "validate", *(str(f) for f, _ in cases.values())],
        capture_output=True, text=True, check=False,
    )  # fmt: skip
    assert result.returncode == 2, result.stderr
    assert "Traceback" not in result.stdout + result.stderr
    assert result.stderr == f"0 of {len(cases)} scenarios valid\n"


def test_a_map_error_keeps_the_tools_lines_under_one_problem(tmp_path):
    file = _bad_inputs(tmp_path)["netconvert rejects"][0]
    result = validate_scenario(file)
    assert len(result.problems) == 1 and result.road_map is None
    first, *rest = result.problems[0].splitlines()
    assert first.startswith(f"{file}: map: ") and rest and all(line.startswith("    ") for line in rest)


# ---------------------------------------------------------------------------- bounds on the map
def test_a_huge_sumo_flow_rate_names_its_field_before_sumo_starts(tmp_path, capsys):
    data = with_(CROSS, traffic={"engine": "sumo", "flows": [{"id": "f", "route": ["west_in"], "rate": 1e9}]})
    file = write(tmp_path, data)
    code, out, _ = validate_cli(capsys, file)
    assert (code, out) == (
        2,
        [f"{file}: traffic.flows[0].rate: input should be less than or equal to 10000, got 1000000000.0"],
    )


def test_a_depart_speed_far_above_the_lane_limit_names_its_field(tmp_path, capsys):
    data = with_(CROSS, traffic={"trips": [{"id": "t", "route": ["east_in"], "depart_lane": 0, "depart_speed": 25}]})
    file = write(tmp_path, data)
    code, out, _ = validate_cli(capsys, file)
    assert code == 2
    assert out == [f"{file}: traffic.trips[0].depart_speed: lane 0 of road 'east_in' has a speed limit of 13.89 m/s; "
                   "expected at most 1.5 times that (20.84 m/s), got 25"]  # fmt: skip


# ---------------------------------------------------------------------------- what ships stays valid
@pytest.mark.parametrize("name", list_scenarios())
def test_every_builtin_scenario_is_valid(name, library_scenario, capsys):
    library_scenario(name)  # its built-in map must build (a missing recipe fails)
    result = validate_scenario(name)
    assert result.valid, "\n".join(result.problems)


def test_scenario_list_then_validate_every_listed_scenario(capsys, library_maps_available):
    assert main(["scenario", "list"]) == 0
    table = capsys.readouterr().out
    listed = [name for name in list_scenarios() if f" {name} " in table]
    assert listed == list_scenarios()
    code, out, _ = validate_cli(capsys, *listed)
    assert code == 0 and len(out) == len(listed) and all(": valid (" in line for line in out), out


@pytest.mark.parametrize("path", sorted((ROOT / "configs" / "benchmark").glob("*.yaml")), ids=lambda p: p.name)
def test_every_shipped_benchmark_config_loads_and_its_scenarios_are_valid(path):
    if path.stem == "metrics":
        from smarts.benchmark.metrics.params import load_params

        params = load_params(path)
        # The paper's weights: PR 0.1, RC 0.45, Humanness 0.15, MTE or SFD 0.3.
        w = params.weights
        assert (w.pr, w.rc, w.humanness, w.mte, w.sfd) == pytest.approx((0.1, 0.45, 0.15, 0.3, 0.3))
        return
    from smarts.benchmark.suites import load_suite

    suite = load_suite(path)
    assert suite.scenarios
    for item in suite.scenarios:
        result = validate_spec(item.spec)
        assert result.valid, "\n".join(result.problems)
