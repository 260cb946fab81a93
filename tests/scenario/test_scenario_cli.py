"""The ``smarts`` command line: scenario list/show and map list/build."""

from __future__ import annotations

import subprocess
import sys

import yaml

from smarts.__main__ import main
from smarts.scenario import BUILTIN_MAPS, list_scenarios, load_scenario, scenario_to_dict


def test_scenario_list_shows_every_scenario_with_map_agents_steps(capsys, library_maps_available):
    assert main(["scenario", "list"]) == 0
    out = capsys.readouterr().out
    for name in list_scenarios():
        spec = load_scenario(name)
        row = next(line for line in out.splitlines() if f" {name} " in line)
        cells = [c.strip() for c in row.strip("│ ").split("│")]
        assert cells == [name, spec.map, str(len(spec.agents)), str(spec.episode_steps)]


def test_scenario_show_prints_the_validated_spec_as_yaml(capsys):
    assert main(["scenario", "show", "intersection_4way_left"]) == 0
    out = capsys.readouterr().out
    assert yaml.safe_load(out) == scenario_to_dict(load_scenario("intersection_4way_left"))
    assert "action_space: relative_target_pose" in out  # defaults are shown explicitly


def test_scenario_show_accepts_a_file(tmp_path, capsys):
    path = tmp_path / "solo.yaml"
    path.write_text(
        "map: builtin:straight_3lane\nagents:\n  - mission: {start: {road: main, lane: 2}, goal: {endless: true}}\n",
        encoding="utf-8",
    )
    assert main(["scenario", "show", str(path)]) == 0
    shown = yaml.safe_load(capsys.readouterr().out)
    assert shown["name"] == "solo" and shown["agents"][0]["id"] == "agent_0"


def test_scenario_show_reports_errors_on_stderr(tmp_path, capsys):
    assert main(["scenario", "show", "no_such_scenario"]) == 2
    err = capsys.readouterr().err
    assert err.startswith("error: unknown scenario 'no_such_scenario'")
    bad = tmp_path / "bad.yaml"
    bad.write_text("map: builtin:straight_2lane\nagents: []\n", encoding="utf-8")
    assert main(["scenario", "show", str(bad)]) == 2
    assert f"{bad}: agents: list should have at least 1 item" in capsys.readouterr().err


def test_map_list_and_build(capsys, monkeypatch, map_cache_dir, built_maps):
    assert main(["map", "list"]) == 0
    out = capsys.readouterr().out
    assert all(name in out for name in BUILTIN_MAPS)
    monkeypatch.setenv("SMARTS_CACHE_DIR", str(map_cache_dir))
    assert main(["map", "build", "t_junction"]) == 0
    assert capsys.readouterr().out.strip() == str(built_maps["t_junction"])
    assert main(["map", "build", "moon_base"]) == 2
    assert "unknown built-in map 'moon_base'" in capsys.readouterr().err


def test_no_command_prints_help(capsys):
    assert main([]) == 2
    assert "scenario" in capsys.readouterr().out


def test_python_dash_m_smarts_runs(library_maps_available):
    result = subprocess.run(
        [sys.executable, "-m", "smarts", "scenario", "list"],
        capture_output=True,
        text=True,
        check=False,
    )
    assert result.returncode == 0, result.stderr
    assert "highway_merge" in result.stdout


def test_scenario_show_build_counts_roads_and_checks_missions(capsys, monkeypatch, map_cache_dir, built_maps):
    """``show --build`` compiles the map with the real map compiler."""
    monkeypatch.setenv("SMARTS_CACHE_DIR", str(map_cache_dir))
    assert main(["scenario", "show", "t_junction_left", "--build"]) == 0
    out = capsys.readouterr().out
    assert f"# map file: {built_maps['t_junction']}" in out
    assert "# roads: 6 (" in out
    assert "# missions and traffic: every road, lane, offset, speed and route checked on the map" in out
