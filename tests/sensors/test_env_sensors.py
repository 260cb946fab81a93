"""Interfaces in the environments: per-agent spaces, grouped batches, the ego view for render()."""

import numpy as np
import pytest
from pettingzoo.test import parallel_api_test

from smarts.core.vehicle_table import VehicleType
from smarts.env import DrivingEnv, DrivingParallelEnv
from smarts.sensors.interface import (
    AgentInterface,
    EgoInterface,
    LidarInterface,
    NeighboursInterface,
)
from smarts.sensors.observation import ObservationBuilder, ObservationConfig
from smarts.sensors.rasters import EGO, OCCLUSION_VISIBLE, SHADED_PALETTE
from tests.builders import agent, make_spec
from tests.sensors.support import LANE0_Y, LANE1_Y, observe, place, scene_env

LIDAR = {"lidar": {"rays": 16, "range": 20}}
RASTERS = {"rasters": {"size": 16, "resolution": 1.0, "rgb": True}, "occlusion": {"enabled": True}}


def _mixed_spec(**extra):
    return make_spec(
        [
            agent(lane=0, offset=10.0, interface=LIDAR),
            agent(lane=1, offset=10.0, interface=RASTERS),
            agent(lane=0, offset=30.0, interface=LIDAR),
            agent(lane=1, offset=30.0),
        ],
        **extra,
    )


def test_agents_with_different_interfaces_get_their_own_spaces_and_one_pass_per_group():
    env = DrivingParallelEnv(_mixed_spec())
    assert len(env.sensors.builders) == 3
    spaces = {a: env.observation_space(a) for a in env.possible_agents}
    assert spaces["agent_0"] is spaces["agent_2"]
    assert "lidar" in spaces["agent_0"].spaces and "rgb" not in spaces["agent_0"].spaces
    assert "rgb" in spaces["agent_1"].spaces and spaces["agent_1"]["rasters"].shape == (5, 16, 16)
    assert set(spaces["agent_3"].spaces) == {
        "ego", "neighbours", "neighbour_mask", "waypoints", "waypoint_mask", "goal", "signal", "events"
    }  # fmt: skip
    obs, _ = env.reset(seed=0)
    for _ in range(3):
        for a in env.agents:
            assert spaces[a].contains(obs[a]), a
        obs, *_ = env.step({a: np.array([1.0, 0.0, 0.0], dtype=np.float32) for a in env.agents})
    batches = env.sensors.build(env.sim, env.sim.active_agents)
    assert [m.tolist() for m, _ in batches] == [[0, 2], [1], [3]]
    env.close()


def test_mixed_interfaces_pass_the_pettingzoo_api_test():
    env = DrivingParallelEnv(_mixed_spec(episode_steps=30))
    parallel_api_test(env, num_cycles=30)
    env.close()


def test_the_default_interface_observation_equals_the_basic_one():
    """What the env hands out (the sensor suite's grouped pass) is the plain observation of the
    default config, and its ego and neighbour features are the vehicle table's state."""
    env = DrivingParallelEnv("straight_2lane_cruise")
    env.reset(seed=0)
    obs, *_ = env.step({a: np.array([1.0, 0.0, 0.0], dtype=np.float32) for a in env.agents})
    sim, t = env.sim, env.sim.table
    agents = sim.active_agents
    basic = ObservationBuilder(ObservationConfig()).build(sim, agents)
    assert set(obs[env.agents[0]]) == set(basic)
    for k, a in enumerate(agents.tolist()):
        ours = obs[sim.agent_ids[a]]
        for key in basic:
            np.testing.assert_array_equal(ours[key], basic[key][k], err_msg=key)
        # Independently of any builder: the ego's speed, lane width and size from the table and map.
        row = sim.agent_row[a]
        ego = ours["ego"]
        assert ego[0] == pytest.approx(t.speed[row], abs=1e-5)
        assert ego[8] == pytest.approx(sim.road_map.lane_width[t.lane[row]], abs=1e-5)
        assert (ego[10], ego[11]) == pytest.approx((t.length[row], t.width[row]), abs=1e-5)
        # The nearest other vehicle, in the ego frame.
        others = [r for r in t.alive_rows if r != row]
        assert others  # two agents: each is the other's neighbour
        near = min(others, key=lambda r: np.hypot(t.x[r] - t.x[row], t.y[r] - t.y[row]))
        dx, dy = t.x[near] - t.x[row], t.y[near] - t.y[row]
        c, s = np.cos(t.heading[row]), np.sin(t.heading[row])
        assert ours["neighbour_mask"][0] == 1.0
        assert ours["neighbours"][0, :2] == pytest.approx((c * dx + s * dy, c * dy - s * dx), abs=1e-4)
    env.close()


def test_observation_argument_overrides_interfaces_for_all_or_named_agents():
    spec = _mixed_spec()
    env = DrivingParallelEnv(spec, observation=ObservationConfig(neighbours=3))
    assert len(env.sensors.builders) == 1
    assert env.observation_space("agent_1")["neighbours"].shape == (3, 9)
    env.close()
    env = DrivingParallelEnv(spec, observation={"agent_3": AgentInterface(lidar=LidarInterface(rays=8))})
    assert env.observation_space("agent_3")["lidar"].shape == (8,)
    assert env.observation_space("agent_0")["lidar"].shape == (16,)
    env.close()
    with pytest.raises(ValueError, match=r"observation: no agents \['agent_9'\]"):
        DrivingParallelEnv(spec, observation={"agent_9": AgentInterface()})


def test_social_agents_with_another_interface_still_drive():
    spec = make_spec(
        [
            agent(lane=0, offset=10.0, interface=LIDAR),
            agent(lane=1, offset=10.0, policy="zoo:keep-lane"),
        ]
    )
    env = DrivingParallelEnv(spec)
    obs, _ = env.reset(seed=0)
    assert list(obs) == ["agent_0"]
    start = env.sim.table.x[env.sim.agent_row[1]]
    for _ in range(10):
        obs, *_ = env.step({"agent_0": np.array([1.0, 0.0, 0.0], dtype=np.float32)})
    assert env.sim.table.x[env.sim.agent_row[1]] > start + 5.0
    assert obs["agent_0"]["lidar"].shape == (16,)
    env.close()


def test_extended_neighbours_carry_speed_lane_and_type():
    interface = AgentInterface(neighbours=NeighboursInterface(extended=True))
    env = scene_env(3, interface)
    place(env, 0, 50.0, LANE0_Y)
    place(env, 1, 60.0, LANE1_Y, speed=7.0, accel=0.5)
    place(env, 2, 40.0, LANE0_Y)
    env.sim.table.vtype[env.sim.agent_row[2]] = int(VehicleType.TRUCK)
    nb = observe(env)["neighbours"][0]
    ahead = nb[np.argmax(nb[:, 0])]
    behind = nb[np.argmin(nb[:, 0])]
    assert ahead[0] == pytest.approx(10.0) and ahead[9] == pytest.approx(7.0) and ahead[10] == pytest.approx(0.5)
    assert ahead[12] == 1.0 and ahead[13] == 1.0  # lane 1, same road
    np.testing.assert_array_equal(ahead[14:], [1, 0, 0, 0, 0, 0])  # passenger
    assert behind[12] == 0.0
    np.testing.assert_array_equal(behind[14:], [0, 0, 1, 0, 0, 0])  # truck
    env.close()


def test_extended_ego_has_the_angular_acceleration_of_the_last_step():
    env = DrivingParallelEnv(
        make_spec([agent(lane=0, offset=10.0)]), observation=AgentInterface(ego=EgoInterface(extended=True))
    )
    obs, _ = env.reset(seed=0)
    assert obs["agent_0"]["ego"].shape == (13,) and obs["agent_0"]["ego"][12] == 0.0
    rates = []
    for dh in (0.0, 0.02, 0.05):
        obs, *_ = env.step({"agent_0": np.array([1.0, 0.0, dh], dtype=np.float32)})
        rates.append(float(obs["agent_0"]["ego"][4]))
        # Building again in the same step gives the same value.
        again = env.builder.build(env.sim, env.sim.active_agents)["ego"][0, 12]
        assert again == obs["agent_0"]["ego"][12]
    assert obs["agent_0"]["ego"][12] == pytest.approx((rates[2] - rates[1]) / 0.1, rel=1e-4)
    assert rates[2] != rates[1]
    env.close()


def test_render_can_follow_an_agent_with_the_ego_view():
    env = DrivingParallelEnv("straight_2lane_cruise", render_mode="rgb_array", render_view="ego:agent_1")
    env.reset(seed=0)
    frame = env.render()
    assert frame.shape == (256, 256, 3) and frame.dtype == np.uint8
    np.testing.assert_array_equal(frame[128, 128], SHADED_PALETTE[OCCLUSION_VISIBLE][EGO])
    env.close()
    gym_env = DrivingEnv("straight_2lane_cruise", render_mode="rgb_array", render_view="ego")
    gym_env.reset(seed=0)
    assert gym_env.render().shape == (256, 256, 3)
    gym_env.close()
    with pytest.raises(ValueError, match="render_view must be"):
        DrivingParallelEnv("straight_2lane_cruise", render_view="ego:nobody")


def test_gym_env_takes_an_interface():
    env = DrivingEnv("straight_2lane_cruise", observation=AgentInterface(lidar=LidarInterface(rays=12)))
    obs, _ = env.reset(seed=0)
    assert env.observation_space.contains(obs) and obs["lidar"].shape == (12,)
    # The single-agent env drives agent_0 alone: straight ahead the lane runs on beyond the range,
    # sideways the road edges are within it.
    assert obs["lidar"][0] == pytest.approx(30.0) and obs["lidar_hit"][0] == 0
    assert obs["lidar_hit"][3] == 3 and obs["lidar"][3] < 5.0
    env.close()
