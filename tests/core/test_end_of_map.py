"""The end of the map is not the edge of the road: driving to the end of a route lane that leads
nowhere ends the episode as cut off (truncated), not as off road; leaving the road sideways, or
the end of a lane that is not on the route, still is off road."""

import numpy as np

from smarts.core.events import Event
from smarts.env import DrivingParallelEnv
from tests.builders import agent, make_spec

ROAD = 300.0  # builtin:straight_2lane, road "main" along +x


def _drive(spec, action, steps=200):
    env = DrivingParallelEnv(spec)
    env.reset(seed=0)
    for step in range(steps):
        obs, rewards, terms, truncs, infos = env.step({a: np.asarray(action, float) for a in env.agents})
        if not env.agents:
            return step, terms, truncs, infos, env
    raise AssertionError("the episode did not end")


def test_driving_to_the_end_of_the_road_is_cut_off_not_off_road():
    spec = make_spec([agent(offset=ROAD - 30.0, speed=10.0)], episode_steps=200)
    step, terms, truncs, infos, env = _drive(spec, [1.0, 0.0, 0.0])
    assert truncs["agent_0"] and not terms["agent_0"]
    assert "off_road" not in infos["agent_0"].get("events", [])
    assert "partial_off_road" not in infos["agent_0"].get("events", [])
    front = env.sim.table.x[env.sim.agent_row[0]] + 0.5 * env.sim.table.length[env.sim.agent_row[0]]
    assert front >= ROAD - 1.0 and step < 40  # it ends as its front reaches the road's end


def test_leaving_the_road_sideways_is_still_off_road():
    spec = make_spec([agent(offset=50.0, speed=5.0)], episode_steps=200)
    _, terms, truncs, infos, _ = _drive(spec, [0.5, -0.5, 0.0])  # steering hard right off the road
    assert terms["agent_0"] and "off_road" in infos["agent_0"]["events"]


def test_the_end_of_a_lane_off_the_route_is_off_road():
    """An agent routed into the side road of the T junction that drives straight on to the end of
    the main road (not on its route) leaves the road there."""
    spec = make_spec(
        [agent(start_road="west_in", offset=30.0, speed=10.0, goal={"road": "south_out", "offset": 30.0})],
        map_name="t_junction", episode_steps=400,
        events={"terminate_on": ["collision", "off_road", "reached_goal", "max_steps"]},
    )  # fmt: skip
    _, terms, truncs, infos, env = _drive(spec, [1.0, 0.0, 0.0], steps=400)
    assert terms["agent_0"] and "off_road" in infos["agent_0"]["events"]
    row = env.sim.agent_row[0]
    assert env.sim.road_map.road_ids[env.sim.road_map.lane_road[env.sim.table.lane[row]]] == "east_out"


def test_the_event_vector_keeps_its_layout():
    assert len(Event) == 8  # policies trained on the events block keep their inputs
