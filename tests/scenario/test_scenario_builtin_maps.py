"""Built-in maps: generated XML compiled by the real netconvert, checked with sumolib."""

from __future__ import annotations

import dataclasses
import logging
import os
import shutil
import signal
import subprocess
import sys
import warnings
import xml.etree.ElementTree as ET
from concurrent.futures import ThreadPoolExecutor

import pytest
import sumolib

from smarts import cache
from smarts.maps import load_map
from smarts.maps.loader import clear_memory_cache
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
from tests.builders import PERMISSIONS_SKIP

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
    assert net.getNode("end").getCoord()[0] - net.getNode("start").getCoord()[0] == pytest.approx(455.0)
    assert net.getEdge("ramp").getLength() == pytest.approx(135.0, abs=5.0)
    assert [c.getToLane().getID() for c in net.getLane("ramp_0").getOutgoing()] == ["main_1_0"]
    path, _ = net.getShortestPath(net.getEdge("main_0"), net.getEdge("main_2"))
    assert [e.getID() for e in path] == ["main_0", "main_1", "main_2"]
    for i in range(6):  # every through lane continues beside the acceleration lane
        assert [c.getToLane().getID() for c in net.getLane(f"main_0_{i}").getOutgoing()] == [f"main_1_{i + 1}"]


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
    # The generated inputs are kept next to the output for inspection, with their checksums.
    assert sorted(p.name for p in changed.parent.iterdir()) == [
        "SHA256SUMS",
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


# ---------------------------------------------------------------- damaged and unwritable caches
def test_truncated_netconvert_output_in_the_cache_is_rebuilt(tmp_path, built_maps, caplog):
    net = compile_map(BUILTIN_MAPS["t_junction"], tmp_path)
    whole = net.read_bytes()
    assert whole == built_maps["t_junction"].read_bytes()
    net.write_bytes(whole[: len(whole) // 2])  # e.g. a copy cut short by a full disk
    caplog.set_level(logging.WARNING)
    for _ in range(2):  # rebuilt once, then reused
        again = builtin_map_path("t_junction", tmp_path)
        assert again == net and again.read_bytes() == whole
        clear_memory_cache()
        assert "south_in" in load_map(again, cache_dir=tmp_path / "maps").road_ids
    rebuilt = [r for r in caplog.records if "rebuilding the cached built-in map" in r.getMessage()]
    assert len(rebuilt) == 1 and "does not match its recorded SHA-256" in rebuilt[0].getMessage()
    assert os.listdir(cache_root(tmp_path)) == [net.parent.name]


@pytest.mark.parametrize("damage", ["manifest removed", "input removed", "entry is a file"])
def test_incomplete_cache_entry_is_rebuilt(tmp_path, damage):
    recipe = BUILTIN_MAPS["straight_2lane"]
    net = compile_map(recipe, tmp_path)
    whole = net.read_bytes()
    if damage == "manifest removed":
        (net.parent / "SHA256SUMS").unlink()
    elif damage == "input removed":
        (net.parent / "straight_2lane.edg.xml").unlink()
    else:
        shutil.rmtree(net.parent)
        net.parent.write_text("")
    assert compile_map(recipe, tmp_path) == net
    assert net.read_bytes() == whole
    assert (net.parent / "straight_2lane.edg.xml").is_file()


def test_build_killed_before_it_is_in_place_leaves_no_entry(tmp_path):
    code = (
        "import os, signal, sys\n"
        "from smarts.scenario.builtin_maps import BUILTIN_MAPS, compile_map\n"
        "real = os.rename\n"
        "def dying(src, dst):\n"
        "    if '.tmp-build' in str(src):\n"
        "        os.kill(os.getpid(), signal.SIGKILL)\n"
        "    return real(src, dst)\n"
        "os.rename = dying\n"
        "compile_map(BUILTIN_MAPS['straight_2lane'], sys.argv[1])\n"
    )
    done = subprocess.run([sys.executable, "-c", code, str(tmp_path)])
    assert done.returncode == -signal.SIGKILL
    (left,) = os.listdir(cache_root(tmp_path))
    assert left.startswith(".tmp-build-straight_2lane-")  # a temporary name, never read as an entry
    net = compile_map(BUILTIN_MAPS["straight_2lane"], tmp_path)
    assert sumolib.net.readNet(str(net)).getEdge("main").getLaneNumber() == 2
    assert sorted(os.listdir(cache_root(tmp_path))) == sorted([left, net.parent.name])


def test_unwritable_cache_builds_in_a_temporary_one_with_one_warning(tmp_path, fresh_fallback):
    blocker = tmp_path / "file"
    blocker.write_text("not a folder")
    wanted = blocker / "cache"  # cannot be created, even by root
    clear_memory_cache()
    with pytest.warns(cache.UnwritableCacheWarning) as record:
        net = builtin_map_path("straight_2lane", wanted)
        road_map = load_map(net, cache_dir=wanted / "maps")
        assert builtin_map_path("straight_2lane", wanted) == net  # reused, no second warning
    assert len(record) == 1
    message = str(record[0].message)
    assert str(wanted / "netconvert") in message and "SMARTS_CACHE_DIR" in message
    fallback = cache.fallback_home(create=False)
    assert fallback.name.startswith("smarts-cache-") and net.is_relative_to(fallback)
    assert road_map.lane_ids == ["main_0", "main_1"]
    assert cache.check_manifest(net.parent, [net.name]) is None


def test_unwritable_cache_from_the_environment(tmp_path, monkeypatch, fresh_fallback):
    blocker = tmp_path / "file"
    blocker.write_text("not a folder")
    monkeypatch.setenv("SMARTS_CACHE_DIR", str(blocker / "cache"))
    with pytest.warns(cache.UnwritableCacheWarning, match=r"cache/netconvert.*SMARTS_CACHE_DIR"):
        net = builtin_map_path("straight_2lane")
    assert net.is_relative_to(cache.fallback_home(create=False))


@PERMISSIONS_SKIP
def test_read_only_cache_falls_back_and_still_reads_its_entries(tmp_path, fresh_fallback):
    built = compile_map(BUILTIN_MAPS["straight_2lane"], tmp_path)
    for folder in (tmp_path, cache_root(tmp_path)):
        folder.chmod(0o500)
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("error")  # an intact entry is read without writing anything
            assert compile_map(BUILTIN_MAPS["straight_2lane"], tmp_path) == built
        with pytest.warns(cache.UnwritableCacheWarning, match="SMARTS_CACHE_DIR") as record:
            other = compile_map(BUILTIN_MAPS["t_junction"], tmp_path)
        assert len(record) == 1 and str(cache_root(tmp_path)) in str(record[0].message)
        assert other.is_relative_to(cache.fallback_home(create=False))
    finally:
        for folder in (tmp_path, cache_root(tmp_path)):
            folder.chmod(0o700)


def test_netconvert_version_is_asked_once_per_binary(tmp_path, monkeypatch):
    """The version (part of every map's cache key) is remembered on disk for the binary (path,
    size, modification time), so later processes do not run netconvert for it; another binary at
    the same path is asked again."""
    from smarts.scenario import builtin_maps

    monkeypatch.setenv(cache.ENV_VAR, str(tmp_path / "cache"))
    asked = []
    ask = builtin_maps._ask_netconvert_version
    monkeypatch.setattr(builtin_maps, "_ask_netconvert_version", lambda binary: asked.append(binary) or ask(binary))
    real = builtin_maps.netconvert_version.__wrapped__
    first = real()
    assert first.startswith("Eclipse SUMO netconvert") and len(asked) == 1
    assert real() == first and len(asked) == 1  # as a new process would: from the file
    stand_in = tmp_path / "netconvert"  # a binary replaced in place: its size and time change
    stand_in.write_text("#!/bin/sh\necho 'Eclipse SUMO netconvert 0.0.1'\n")
    stand_in.chmod(0o755)
    monkeypatch.setattr(builtin_maps, "netconvert_binary", lambda: str(stand_in))
    assert real() == "Eclipse SUMO netconvert 0.0.1" and len(asked) == 2
    stand_in.write_text("#!/bin/sh\necho 'Eclipse SUMO netconvert 0.0.22'\n")
    assert real() == "Eclipse SUMO netconvert 0.0.22" and len(asked) == 3
    assert real() == "Eclipse SUMO netconvert 0.0.22" and len(asked) == 3
