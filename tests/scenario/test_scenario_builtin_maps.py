"""Built-in maps: generated XML compiled by the real netconvert, checked with sumolib."""

from __future__ import annotations

import dataclasses
import os
import xml.etree.ElementTree as ET
from concurrent.futures import ThreadPoolExecutor

import pytest
import sumolib

from smarts.scenario import BUILTIN_MAPS, NetconvertError, ScenarioError, builtin_map_path
from smarts.scenario.builtin_maps import (
    MapRecipe,
    PlainEdge,
    PlainNetwork,
    PlainNode,
    cache_key,
    cache_root,
    compile_map,
)

FOUR_ARMS = [f"{arm}_{way}" for arm in ("west", "north", "east", "south") for way in ("in", "out")]

# name -> {edge: lane count}, lane width, {edge: speed} (default speed for unlisted edges)
EXPECTED = {
    "straight_2lane": ({"main": 2}, 3.2, {}),
    "straight_3lane": ({"main": 3}, 3.2, {}),
    "straight_2lane_twoway": ({"eastbound": 1, "westbound": 1}, 3.2, {}),
    "t_junction": ({e: 1 for e in FOUR_ARMS if not e.startswith("north")}, 3.2, {}),
    "highway_merge_exit": (
        {"main_0": 3, "main_1": 4, "main_2": 3, "main_3": 4, "main_4": 3, "ramp": 1, "exit": 1},
        3.5,
        {**{f"main_{i}": 25.0 for i in range(5)}, "ramp": 16.67, "exit": 16.67},
    ),
    "highway_6lane_ramp": ({"main_0": 6, "main_1": 7, "main_2": 6, "ramp": 1}, 3.66, {}),
    "highway_6lane_ramp_long": ({"main_0": 6, "main_1": 7, "main_2": 6, "ramp": 1}, 3.66, {}),
    # Two lanes per arm: a 2 m sidewalk (lane 0) and the car lane (lane 1).
    "intersection_4way_1lane_peds": ({e: 2 for e in FOUR_ARMS}, 3.2, {}),
    **{
        f"intersection_4way_{n}lane{suffix}": ({e: n for e in FOUR_ARMS}, 3.2, {})
        for n in (1, 2, 3)
        for suffix in ("", "_signal")
    },
}


def test_every_builtin_map_is_covered():
    assert set(EXPECTED) == set(BUILTIN_MAPS)


@pytest.mark.parametrize("name", sorted(EXPECTED))
def test_map_has_expected_edges_lanes_widths_speeds(name, sumo_nets):
    net = sumo_nets[name]
    lane_counts, width, speeds = EXPECTED[name]
    edges = {e.getID(): e for e in net.getEdges(withInternal=False)}
    assert {e: edges[e].getLaneNumber() for e in edges} == lane_counts
    for edge_id, edge in edges.items():
        for lane in edge.getLanes():
            if lane.allows("pedestrian") and not lane.allows("passenger"):
                assert lane.getWidth() == pytest.approx(2.0)  # a sidewalk
                continue
            assert lane.getWidth() == pytest.approx(width)
            assert lane.getSpeed() == pytest.approx(speeds.get(edge_id, 13.89))
            assert lane.getID() == f"{edge_id}_{lane.getIndex()}"


@pytest.mark.parametrize("name", ["straight_2lane", "straight_3lane", "straight_2lane_twoway"])
def test_straight_roads_are_300_m(name, sumo_nets):
    for edge in sumo_nets[name].getEdges():
        assert edge.getLength() == pytest.approx(300.0)


def test_twoway_road_directions_are_opposite_and_side_by_side(sumo_nets):
    net = sumo_nets["straight_2lane_twoway"]
    east = net.getEdge("eastbound").getLane(0).getShape()
    west = net.getEdge("westbound").getLane(0).getShape()
    assert east[-1][0] > east[0][0] and west[-1][0] < west[0][0]
    # Right-hand traffic: eastbound south of the centre line, westbound north of it.
    assert east[0][1] == pytest.approx(-1.6) and west[0][1] == pytest.approx(1.6)
    # Vehicles leave the map at the ends instead of making a U-turn.
    assert net.getEdge("eastbound").getLane(0).getOutgoing() == []


@pytest.mark.parametrize("lanes", [1, 2, 3])
def test_intersection_arms_are_about_100_m_with_all_turns(lanes, sumo_nets):
    net = sumo_nets[f"intersection_4way_{lanes}lane"]
    for edge_id in FOUR_ARMS:
        assert 90.0 < net.getEdge(edge_id).getLength() < 110.0
    west_in = net.getEdge("west_in")
    directions = {c.getDirection() for lane in west_in.getLanes() for c in lane.getOutgoing()}
    assert {"s", "l", "r", "t"} <= directions  # straight, left, right and a U-turn
    targets = {e.getID() for e in west_in.getOutgoing()}
    assert targets == {"east_out", "north_out", "south_out", "west_out"}
    # No U-turn at the map border.
    assert all(not lane.getOutgoing() for lane in net.getEdge("west_out").getLanes())


@pytest.mark.parametrize("lanes", [1, 2, 3])
def test_signalised_intersections_have_a_traffic_light(lanes, sumo_nets):
    signal = sumo_nets[f"intersection_4way_{lanes}lane_signal"]
    plain = sumo_nets[f"intersection_4way_{lanes}lane"]
    assert signal.getNode("center").getType() == "traffic_light"
    assert [tls.getID() for tls in signal.getTrafficLights()] == ["center"]
    assert plain.getNode("center").getType() == "priority"
    assert plain.getTrafficLights() == []


def test_t_junction_side_road_connects_both_ways(sumo_nets):
    net = sumo_nets["t_junction"]
    assert {e.getID() for e in net.getEdge("south_in").getOutgoing()} >= {"west_out", "east_out"}
    assert net.getShortestPath(net.getEdge("west_in"), net.getEdge("south_out"))[0] is not None


def test_highway_merge_exit_topology(sumo_nets):
    net = sumo_nets["highway_merge_exit"]

    def targets(lane_id):
        return sorted(c.getToLane().getID() for c in net.getLane(lane_id).getOutgoing())

    assert targets("ramp_0") == ["main_1_0"]  # the ramp becomes the acceleration lane
    assert targets("main_1_0") == ["main_2_0"]  # which ends by merging into lane 0
    assert targets("main_3_0") == ["exit_0"]  # the deceleration lane leads to the exit
    path, _ = net.getShortestPath(net.getEdge("ramp"), net.getEdge("exit"))
    assert [e.getID() for e in path] == ["ramp", "main_1", "main_2", "main_3", "exit"]
    assert net.getNode("end").getCoord()[0] - net.getNode("start").getCoord()[0] == 600.0
    # Junction shapes take a few metres from each piece.
    assert 560.0 < sum(net.getEdge(f"main_{i}").getLength() for i in range(5)) < 600.0


def test_highway_6lane_ramp_dimensions(sumo_nets):
    net = sumo_nets["highway_6lane_ramp"]
    assert net.getNode("end").getCoord()[0] - net.getNode("start").getCoord()[0] == pytest.approx(
        455.0
    )
    assert net.getEdge("ramp").getLength() == pytest.approx(135.0, abs=5.0)
    assert [c.getToLane().getID() for c in net.getLane("ramp_0").getOutgoing()] == ["main_1_0"]
    path, _ = net.getShortestPath(net.getEdge("main_0"), net.getEdge("main_2"))
    assert [e.getID() for e in path] == ["main_0", "main_1", "main_2"]
    for i in range(6):  # every through lane continues beside the acceleration lane
        assert [c.getToLane().getID() for c in net.getLane(f"main_0_{i}").getOutgoing()] == [
            f"main_1_{i + 1}"
        ]


def test_node_coordinates_are_kept(built_maps):
    """Offsets are not normalised, so scenario goal positions match the generator's coordinates."""
    root = ET.parse(built_maps["intersection_4way_1lane"]).getroot()
    junctions = {j.get("id"): j for j in root.iter("junction")}
    assert float(junctions["center"].get("x")) == 0.0
    assert float(junctions["west"].get("x")) == -110.0
    assert root.find("location").get("netOffset") == "0.00,0.00"


def test_cache_reuses_a_build_and_regenerates_on_change(tmp_path):
    recipe = BUILTIN_MAPS["straight_2lane"]
    first = compile_map(recipe, tmp_path)
    mtime = first.stat().st_mtime_ns
    again = compile_map(recipe, tmp_path)
    assert again == first
    assert again.stat().st_mtime_ns == mtime  # netconvert did not run again

    faster = dataclasses.replace(recipe, params={**recipe.params, "speed": 20.0})
    changed = compile_map(faster, tmp_path)
    assert changed != first and changed.parent.parent == first.parent.parent
    assert sumolib.net.readNet(str(changed)).getEdge("main").getSpeed() == pytest.approx(20.0)
    assert sumolib.net.readNet(str(first)).getEdge("main").getSpeed() == pytest.approx(13.89)
    # The generated inputs are kept next to the output for inspection.
    assert sorted(p.name for p in changed.parent.iterdir()) == [
        "straight_2lane.edg.xml",
        "straight_2lane.net.xml",
        "straight_2lane.nod.xml",
    ]


def test_builds_are_byte_identical(tmp_path, built_maps):
    rebuilt = compile_map(BUILTIN_MAPS["t_junction"], tmp_path)
    assert rebuilt != built_maps["t_junction"]
    assert rebuilt.read_bytes() == built_maps["t_junction"].read_bytes()
    assert b"generated on" not in rebuilt.read_bytes()[:300]


def test_cache_key_covers_xml_options_and_netconvert_version():
    files = BUILTIN_MAPS["t_junction"].network().xml_files()
    base = cache_key(files, ("--a",), "netconvert 1.0")
    assert cache_key(files, ("--a",), "netconvert 1.1") != base
    assert cache_key(files, ("--b",), "netconvert 1.0") != base
    edited = {**files, "edg.xml": files["edg.xml"].replace('speed="13.89"', 'speed="13.9"', 1)}
    assert cache_key(edited, ("--a",), "netconvert 1.0") != base
    assert cache_key(dict(files), ("--a",), "netconvert 1.0") == base


def test_concurrent_builds_share_one_complete_entry(tmp_path):
    recipe = BUILTIN_MAPS["intersection_4way_2lane"]
    with ThreadPoolExecutor(max_workers=4) as pool:
        paths = list(pool.map(lambda _: compile_map(recipe, tmp_path), range(4)))
    assert len(set(paths)) == 1
    entries = os.listdir(cache_root(tmp_path))
    assert entries == [paths[0].parent.name]  # no temporary build folders left behind
    assert sumolib.net.readNet(str(paths[0])).getEdge("west_in").getLaneNumber() == 2


def test_cache_dir_comes_from_the_environment(tmp_path, monkeypatch):
    monkeypatch.setenv("SMARTS_CACHE_DIR", str(tmp_path / "env_cache"))
    assert cache_root() == tmp_path / "env_cache" / "netconvert"
    monkeypatch.delenv("SMARTS_CACHE_DIR")
    monkeypatch.setenv("HOME", str(tmp_path / "home"))
    assert cache_root() == tmp_path / "home" / ".cache" / "smarts" / "netconvert"


def test_failed_netconvert_reports_its_stderr_and_leaves_no_entry(tmp_path):
    def broken() -> PlainNetwork:
        return PlainNetwork(
            nodes=(PlainNode("a", 0.0, 0.0),),
            edges=(PlainEdge("road", "a", "nowhere", 1, 10.0, 3.2),),
        )

    with pytest.raises(NetconvertError, match="nowhere") as info:
        compile_map(MapRecipe("broken", "refers to a missing node", broken), tmp_path)
    assert "'broken'" in str(info.value)
    assert os.listdir(cache_root(tmp_path)) == []


def test_unknown_map_name_lists_the_known_ones(tmp_path):
    with pytest.raises(ScenarioError) as info:
        builtin_map_path("straight_9lane", tmp_path)
    message = str(info.value)
    assert "straight_9lane" in message
    assert all(name in message for name in BUILTIN_MAPS)
    assert isinstance(info.value, ValueError)
