"""Every action space drives a vehicle through the env; events that need a map layout."""

import numpy as np
import pytest

from smarts.core.events import Event
from smarts.env import DrivingParallelEnv
from tests.builders import agent, make_spec


def _drive(env, action, steps):
    for _ in range(steps):
        obs, rewards, terms, truncs, infos = env.step({a: action for a in env.agents})
    return obs, rewards, terms, truncs, infos


def test_target_pose_moves_to_a_reachable_world_pose():
    env = DrivingParallelEnv(make_spec([agent(offset=10.0, action_space="target_pose")]))
    env.reset(seed=0)
    row = env.sim.agent_row[0]
    x0 = env.sim.table.x[row]
    env.step({"agent_0": np.array([x0 + 1.0, env.sim.table.y[row], 0.0])})
    assert env.sim.table.x[row] == pytest.approx(x0 + 1.0)
    # A far target is limited to what one step can reach from 10 m/s (max_accel 4 m/s^2).
    env.step({"agent_0": np.array([x0 + 100.0, env.sim.table.y[row], 0.0])})
    assert env.sim.table.x[row] - (x0 + 1.0) == pytest.approx(1.04, abs=1e-9)


def test_lane_action_keeps_lane_and_changes_lane_left():
    env = DrivingParallelEnv(make_spec([agent(lane=0, offset=10.0, speed=8.0, action_space="lane")]))
    env.reset(seed=0)
    row = env.sim.agent_row[0]
    _drive(env, np.array([8.0, 0.0]), 30)
    assert env.sim.table.lane[row] == env.sim.road_map.lane("main_0")
    assert abs(env.sim.table.t[row]) < 0.1 and env.sim.table.speed[row] == pytest.approx(8.0, abs=0.1)
    env.step({"agent_0": np.array([8.0, 1.0])})  # change left once, then keep lane
    _drive(env, np.array([8.0, 0.0]), 60)
    assert env.sim.table.lane[row] == env.sim.road_map.lane("main_1")
    assert abs(env.sim.table.t[row]) < 0.2


def test_continuous_action_drives_a_pybullet_car():
    env = DrivingParallelEnv(make_spec([agent(offset=10.0, speed=0.0, action_space="continuous")]))
    env.reset(seed=0)
    row = env.sim.agent_row[0]
    _drive(env, np.array([1.0, 0.0, 0.0]), 20)  # full throttle for 2 s
    assert 4.0 < env.sim.table.speed[row] < 12.0
    assert env.sim.table.x[row] > 10.0 + 3.0
    env.close()


def test_wrong_way_on_a_two_way_road():
    spec = make_spec(
        [agent("eastbound", offset=50.0, speed=5.0, goal={"endless": True})],
        map_name="straight_2lane_twoway",
        events={"terminate_on": ["wrong_way", "off_road"]},
    )
    env = DrivingParallelEnv(spec)
    env.reset(seed=0)
    ev = env.sim.agent_events
    # Turn left across the centre line until the car faces west in the westbound lane's direction.
    for _ in range(40):
        if not env.agents:
            break
        obs, rewards, terms, truncs, infos = env.step({"agent_0": np.array([0.5, 0.05, 0.12])})
    assert ev[0, Event.WRONG_WAY] or "wrong_way" in infos["agent_0"].get("events", [])


def test_off_route_when_turning_away_from_the_route():
    # The route goes straight east; turning right (south) at the junction leaves it.
    spec = make_spec(
        [agent("west_in", offset=80.0, speed=6.0, goal={"road": "east_out", "offset": 20.0})],
        map_name="intersection_4way_1lane",
        events={"terminate_on": ["off_route", "off_road", "collision"]},
    )
    env = DrivingParallelEnv(spec)
    env.reset(seed=0)
    sim = env.sim
    events = []
    for _ in range(120):
        row = sim.agent_row[0]
        east = sim.table.x[row] > 5.0 or sim.table.y[row] < -8.0
        action = np.array([0.6, 0.0, -0.12]) if sim.table.x[row] > -8.0 and not east else np.array([0.6, 0.0, 0.0])
        obs, rewards, terms, truncs, infos = env.step({"agent_0": action})
        events += infos["agent_0"].get("events", [])
        if terms["agent_0"]:
            break
    assert "off_route" in events
    lane = sim.table.lane[sim.agent_row[0]]
    assert sim.road_map.road_ids[sim.road_map.lane_road[lane]] == "south_out"


def test_not_moving_ends_the_episode_when_configured():
    spec = make_spec(
        [agent(offset=10.0, speed=0.0)],
        events={"terminate_on": ["not_moving"], "not_moving_seconds": 2.0},
    )
    env = DrivingParallelEnv(spec)
    env.reset(seed=0)
    for k in range(1, 30):
        obs, rewards, terms, truncs, infos = env.step({"agent_0": np.zeros(3)})
        if terms["agent_0"]:
            break
    assert k == 20 and infos["agent_0"]["events"] == ["not_moving"]


def test_position_goal_is_reached():
    spec = make_spec([agent(offset=10.0, speed=10.0, goal={"position": [40.0, -4.8], "radius": 2.0})])
    env = DrivingParallelEnv(spec)
    obs, _ = env.reset(seed=0)
    goal = obs["agent_0"]["goal"]
    assert goal[3] == 1.0 and goal[0] == pytest.approx(30.0, abs=0.05) and goal[1] == pytest.approx(0.0, abs=0.05)
    assert goal[2] == pytest.approx(30.0, abs=0.6)  # route distance to the goal
    for _ in range(40):
        obs, rewards, terms, truncs, infos = env.step({"agent_0": np.array([1.0, 0.0, 0.0])})
        if terms["agent_0"]:
            break
    assert infos["agent_0"]["events"] == ["reached_goal"] and rewards["agent_0"] > 10.0


def test_lane_action_changes_lane_right():
    env = DrivingParallelEnv(make_spec([agent(lane=1, offset=10.0, speed=8.0, action_space="lane")]))
    env.reset(seed=0)
    row = env.sim.agent_row[0]
    env.step({"agent_0": np.array([8.0, -1.0])})  # change right once, then keep lane
    _drive(env, np.array([8.0, 0.0]), 60)
    assert env.sim.table.lane[row] == env.sim.road_map.lane("main_0")
    assert abs(env.sim.table.t[row]) < 0.2


@pytest.mark.parametrize("space", ["relative_target_pose", "target_pose", "continuous"])
@pytest.mark.parametrize("command, start_lane, end_lane", [(1.0, 0, "main_1"), (-1.0, 1, "main_0")])
def test_lane_relative_commands_change_lanes_both_ways_in_every_space(space, command, start_lane, end_lane):
    spec = make_spec([agent(lane=start_lane, offset=10.0, speed=8.0, action_space=space, controller="lane_relative")])
    env = DrivingParallelEnv(spec)
    env.reset(seed=0)
    row = env.sim.agent_row[0]
    env.step({"agent_0": np.array([-0.4, command])})  # about 8 m/s on this road, one lane change
    _drive(env, np.array([-0.4, 0.0]), 80)
    assert env.sim.table.lane[row] == env.sim.road_map.lane(end_lane), space
    assert abs(env.sim.table.t[row]) < 0.3
    env.close()
