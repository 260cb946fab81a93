"""The built-in scenario library: every file loads, and every mission fits its map."""

from __future__ import annotations

import shutil

import pytest

from smarts.scenario import (
    ScenarioError,
    ScenarioSpec,
    check_map,
    list_scenarios,
    load_scenario,
    scenario_path,
)
from smarts.scenario.library import LIBRARY_DIR

REQUIRED = {
    "straight_2lane_cruise",
    "intersection_4way_left",
    "intersection_4way_signal_right",
    "t_junction_left",
    "highway_merge",
    "highway_exit",
    "highway_6lane_perf",
    "intersection_4way_signal_traffic",
    "highway_merge_traffic",
    "t_junction_social",
    "straight_takeover",
    "intersection_pedestrians",
}


def test_library_lists_the_required_scenarios():
    names = list_scenarios()
    assert REQUIRED <= set(names)
    assert names == sorted(names)
    assert all(scenario_path(n) == LIBRARY_DIR / f"{n}.yaml" for n in names)


@pytest.mark.parametrize("name", list_scenarios())
def test_library_scenario_loads_and_matches_its_map(name, lane_table_maps, library_scenario):
    spec = library_scenario(name)
    assert spec.name == name
    assert spec.builtin_map is not None
    assert spec.agents and len(set(spec.agent_ids)) == len(spec.agents)
    check_map(spec, lane_table_maps[spec.builtin_map])


@pytest.mark.filterwarnings("ignore:Module 'rtree' not available")
@pytest.mark.parametrize("name", list_scenarios())
def test_library_missions_are_routable(name, sumo_nets, library_scenario):
    """Each goal can be reached from the start through the map's connections (via sumolib)."""
    spec = library_scenario(name)
    trips = {t.id: t for t in spec.traffic.trips} if spec.traffic else {}
    net = sumo_nets[spec.builtin_map]
    for agent in spec.agents:
        mission = agent.mission
        goal = mission.goal
        if goal.kind == "endless":
            continue
        if goal.kind == "road":
            goal_edges = {goal.road}
        else:
            lanes = net.getNeighboringLanes(*goal.position, r=goal.radius)
            goal_edges = {lane.getEdge().getID() for lane, _ in lanes}
            assert goal_edges, f"{name}/{agent.id}: no lane within the goal radius"
        start = mission.start
        start_road = start.road if start.take_over is None else trips[start.take_over].roads[0]
        waypoints = [start_road, *mission.route_via]
        for a, b in zip(waypoints[:-1], waypoints[1:], strict=True):
            assert net.getShortestPath(net.getEdge(a), net.getEdge(b))[0], f"{name}/{agent.id}: {a}->{b}"
        reachable = [net.getShortestPath(net.getEdge(waypoints[-1]), net.getEdge(e))[0] for e in goal_edges]
        assert any(reachable), f"{name}/{agent.id}: goal not reachable"


def test_intersection_left_turn_crosses_the_oncoming_agent(sumo_nets):
    spec = load_scenario("intersection_4way_left")
    net = sumo_nets[spec.builtin_map]
    turner, straight = spec.agents
    direction = {
        c.getTo().getID(): c.getDirection()
        for c in net.getEdge(turner.mission.start.road).getConnections(net.getEdge(turner.mission.goal.road))
    }
    assert direction == {turner.mission.goal.road: "l"}
    assert (straight.mission.start.road, straight.mission.goal.road) == ("east_in", "west_out")


@pytest.mark.filterwarnings("ignore:Module 'rtree' not available")
def test_position_goals_sit_on_the_intended_lane_centre(sumo_nets):
    for name, lane_id in (
        ("intersection_4way_signal_right", "east_out_0"),
        ("t_junction_left", "west_out_0"),
    ):
        spec = load_scenario(name)
        goal = spec.agents[0].mission.goal
        near = {
            lane.getID(): dist for lane, dist in sumo_nets[spec.builtin_map].getNeighboringLanes(*goal.position, r=1.0)
        }
        assert near[lane_id] < 0.05, (name, near)


def test_load_scenario_accepts_a_path(tmp_path):
    copy = tmp_path / "mine.yaml"
    shutil.copy(scenario_path("t_junction_left"), copy)
    assert load_scenario(copy) == load_scenario("t_junction_left")
    assert load_scenario(str(copy)).source == str(copy)


def test_unknown_scenario_lists_the_known_ones():
    with pytest.raises(ScenarioError) as info:
        load_scenario("intersection_5way")
    assert "intersection_5way" in str(info.value)
    assert all(n in str(info.value) for n in list_scenarios())
    with pytest.raises(ScenarioError, match="nothere.yaml"):
        load_scenario("nothere.yaml")


def test_perf_scenario_fills_every_through_lane():
    spec = load_scenario("highway_6lane_perf")
    assert spec.builtin_map == "highway_6lane_ramp"
    assert sorted(a.mission.start.lane for a in spec.agents) == list(range(6))
    assert all(a.mission.goal.kind == "endless" for a in spec.agents)
    assert isinstance(spec, ScenarioSpec)
