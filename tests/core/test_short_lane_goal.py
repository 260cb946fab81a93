"""Goals on lanes shorter than one step's travel (common in real networks: lanes under 1.5 m).

The network is real netconvert output: a 1.2 m road 'BC' between two 100 m roads. An agent at
~22 m/s moves 2.2 m per step and never stands on 'BC' at a step; its goal there must still be
reached (and the road after it must not count as leaving the route)."""

from pathlib import Path

import numpy as np
import pytest

from smarts.core.events import Event, crosses_gate, segment_point_distance2
from smarts.env.assembly import build_simulation
from smarts.maps import load_map
from smarts.scenario import read_scenario
from tests.maps.conftest import build_net

NODES = """<nodes>
  <node id="A" x="0" y="0"/><node id="B" x="100" y="0"/>
  <node id="C" x="101.2" y="0"/><node id="D" x="200" y="0"/>
</nodes>"""
EDGES = """<edges>
  <edge id="AB" from="A" to="B" numLanes="2" speed="30"/>
  <edge id="BC" from="B" to="C" numLanes="2" speed="30"/>
  <edge id="CD" from="C" to="D" numLanes="2" speed="30"/>
</edges>"""
STEP = np.array([2.5, 0.0, 0.0])  # relative target pose: ~2.2 m ahead per 0.1 s step


@pytest.fixture(scope="module")
def short_net(tmp_path_factory) -> Path:
    return build_net(tmp_path_factory.mktemp("short"), "short", NODES, EDGES)


def _drive(net, goal, offset=81.0, steps=20):
    spec = read_scenario(
        {
            "name": "short-goal",
            "map": str(net),
            "agents": [
                {
                    "action_space": "relative_target_pose",
                    "mission": {
                        "start": {"road": "AB", "lane": 0, "offset": offset, "speed": 25.0},
                        "goal": goal,
                    },
                }
            ],
        },
        source="short-goal",
    )
    sim = build_simulation(spec)
    sim.reset()
    seen_on_goal_road = False
    goal_road = sim.road_map.road("BC")
    for step in range(steps):
        sim.step({"agent_0": STEP})
        row = sim.agent_row[0]
        lane = sim.table.lane[row]
        seen_on_goal_road |= lane >= 0 and sim.road_map.lane_road[lane] == goal_road
        if sim.agent_done[0]:
            return sim, step, seen_on_goal_road
    return sim, None, seen_on_goal_road


def test_the_goal_road_is_shorter_than_a_step(short_net):
    rm = load_map(short_net)
    assert rm.lane_length[rm.road_lanes(rm.road("BC"))].max() < 1.5


@pytest.mark.parametrize(
    "goal",
    [
        {"road": "BC"},
        {"road": "BC", "lane": 0},
        {"road": "BC", "offset": 0.6},
        {"position": [100.6, -4.8], "radius": 0.5},
    ],
    ids=["any-lane", "lane", "offset", "position"],
)
def test_a_goal_on_a_lane_jumped_over_in_one_step_is_reached(short_net, goal):
    sim, step, seen = _drive(short_net, goal)
    assert not seen  # the agent never stood on the goal road at a step
    assert step is not None, "the goal was never reached"
    events = sim.agent_events[0]
    assert events[Event.REACHED_GOAL]
    assert not events[Event.OFF_ROUTE]


def test_a_goal_on_another_lane_is_not_reached_by_passing_beside_it(short_net):
    """The goal line spans the goal lane only: driving past it on the lane beside it (lane 0,
    the goal on lane 1) does not reach it."""
    sim, step, _ = _drive(short_net, {"road": "BC", "lane": 1}, steps=12)
    assert not sim.agent_events[:, Event.REACHED_GOAL].any()


def test_goal_line_crossing_is_forward_and_between_its_ends():
    gate = np.array([10.0, 0.0, 1.0, 0.0, -2.0, 1.0])  # line x = 10 from y = -2 to y = 1
    assert crosses_gate(9.0, 0.0, 11.0, 0.0, gate)
    assert crosses_gate(9.0, 0.0, 10.0, 0.0, gate)  # reaching the line counts
    assert not crosses_gate(11.0, 0.0, 9.0, 0.0, gate)  # backwards
    assert not crosses_gate(9.0, 1.5, 11.0, 1.5, gate)  # beside it
    assert crosses_gate(9.0, -1.9, 11.0, -1.9, gate)
    assert not crosses_gate(10.5, 0.0, 12.0, 0.0, gate)  # already past
    assert segment_point_distance2(0.0, 0.0, 4.0, 0.0, 2.0, 1.0) == pytest.approx(1.0)
    assert segment_point_distance2(0.0, 0.0, 4.0, 0.0, 6.0, 0.0) == pytest.approx(4.0)
    assert segment_point_distance2(1.0, 1.0, 1.0, 1.0, 1.0, 3.0) == pytest.approx(4.0)
