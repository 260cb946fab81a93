"""The lead: lane continuity across road segments and junctions, gap along the lanes."""

import numpy as np
import pytest

from smarts.core.following import LEAD_SIGHT, lead_state
from smarts.env import DrivingParallelEnv
from smarts.sensors.interface import AgentInterface
from smarts.sensors.observation import LEAD_FEATURE_NAMES
from tests.builders import make_spec


def _place(env, vehicle_id, lane_id, s):
    """Move a vehicle onto a lane at arc length ``s`` (heading along the lane) and re-project."""
    from smarts.core.missions import lane_pose_at

    sim = env.sim
    rm = sim.road_map
    (x, y), h = lane_pose_at(rm, rm.lane(lane_id), s)
    row = sim.table.row_of[vehicle_id]
    sim.table.x[row], sim.table.y[row], sim.table.heading[row] = x, y, h
    sim.update_map_state()


def _spec(map_name, road, follower, lead, follower_lane=0, lead_lane=0):
    from tests.builders import make_spec as build

    agents = [
        {"id": "follower", "mission": {"start": {"road": road, "lane": follower_lane, "offset": follower, "speed": 10.0},
                                       "goal": {"endless": True}, "follow": "lead"}},
        {"id": "lead", "mission": {"start": {"road": road, "lane": lead_lane, "offset": lead, "speed": 8.0},
                                   "goal": {"endless": True}}},
    ]  # fmt: skip
    return build(agents, map_name=map_name)


def test_lead_straight_ahead_is_in_lane_with_the_bumper_gap_along_the_lane():
    env = DrivingParallelEnv(_spec("straight_2lane", "main", 10.0, 30.0))
    env.reset(seed=0)
    st = lead_state(env.sim, np.array([0]))
    assert st.present[0] and st.visible[0] and st.in_lane[0]
    length = env.sim.table.length[env.sim.agent_row[0]]
    assert st.gap[0] == pytest.approx(20.0 - length, abs=1e-6)  # centre distance minus two half lengths
    assert st.dx[0] == pytest.approx(20.0, abs=1e-6) and st.rel_vx[0] == pytest.approx(-2.0, abs=1e-6)


def test_a_lead_in_the_neighbour_lane_or_behind_is_not_in_lane():
    env = DrivingParallelEnv(_spec("straight_2lane", "main", 10.0, 30.0, lead_lane=1))
    env.reset(seed=0)
    st = lead_state(env.sim, np.array([0]))
    assert st.visible[0] and not st.in_lane[0]
    env = DrivingParallelEnv(_spec("straight_2lane", "main", 30.0, 10.0))
    env.reset(seed=0)
    assert not lead_state(env.sim, np.array([0])).in_lane[0]


def test_lane_continuity_holds_across_road_segments():
    # highway_merge_exit's main road is split into segments (main_0, main_1, ...) joined at nodes.
    env = DrivingParallelEnv(_spec("highway_merge_exit", "main_0", 10.0, 20.0))
    env.reset(seed=0)
    rm = env.sim.road_map
    first = rm.lane("main_0_0")
    joint = int(rm.successors(first)[0])  # the short lane through the node between segments
    beyond = int(rm.successors(joint)[0])
    assert rm.road_ids[rm.lane_road[beyond]] != "main_0"
    _place(env, "follower", "main_0_0", float(rm.lane_length[first]) - 10.0)
    _place(env, "lead", rm.lane_ids[beyond], 5.0)
    st = lead_state(env.sim, np.array([0]))
    assert env.sim.table.lane[env.sim.table.row_of["lead"]] == beyond
    assert st.in_lane[0]
    centres = 10.0 + float(rm.lane_length[joint]) + 5.0
    both_halves = env.sim.table.length[env.sim.agent_row[0]]  # two half lengths of equal cars
    assert st.gap[0] == pytest.approx(centres - both_halves, abs=0.3)
    _place(env, "lead", rm.lane_ids[int(rm.lane_left[beyond])], 5.0)  # the next lane over: not mine
    assert not lead_state(env.sim, np.array([0])).in_lane[0]


def test_beyond_sight_the_lead_is_present_but_not_visible():
    env = DrivingParallelEnv(_spec("straight_2lane", "main", 10.0, 10.0 + LEAD_SIGHT + 5.0))
    env.reset(seed=0)
    st = lead_state(env.sim, np.array([0]))
    assert st.present[0] and not st.visible[0] and not st.in_lane[0] and np.isnan(st.gap[0])


def test_the_lead_block_in_the_observation():
    env = DrivingParallelEnv(_spec("straight_2lane", "main", 10.0, 30.0), observation=AgentInterface(lead=True))
    obs, _ = env.reset(seed=0)
    lead = dict(zip(LEAD_FEATURE_NAMES, obs["follower"]["lead"].tolist()))
    assert lead["present"] == lead["visible"] == lead["in_lane"] == 1.0
    assert lead["dx"] == pytest.approx(20.0) and lead["speed"] == pytest.approx(8.0)
    assert lead["gap"] == pytest.approx(20.0 - env.sim.table.length[env.sim.agent_row[0]], abs=1e-4)
    assert env.observation_space("follower")["lead"].shape == (len(LEAD_FEATURE_NAMES),)
    # An agent that follows nobody gets zeros.
    assert not obs["lead"]["lead"].any()


def test_follow_must_name_a_vehicle_of_the_scenario():
    from smarts.scenario import ScenarioError

    agents = [{"mission": {"start": {"road": "main", "offset": 10}, "goal": {"endless": True}, "follow": "ghost"}}]
    with pytest.raises(ScenarioError, match=r"agents\[0\]\.mission\.follow: no vehicle 'ghost' to follow"):
        make_spec(agents)


def test_lead_rows_follow_the_vehicle_not_the_cached_row():
    """The per-agent row cache must notice a lead that left (its row reused by another vehicle),
    came back in another row, or appeared for the first time."""
    from types import SimpleNamespace

    from smarts.core.following import lead_rows
    from smarts.core.vehicle_table import Role, VehicleTable

    table = VehicleTable(8)
    sim = SimpleNamespace(table=table, lead_ids=["lead", None, "late"])
    agents = np.arange(3)
    table.add("lead", owner=0, role=Role.TRAFFIC, x=0.0, y=0.0, heading=0.0)
    table.add("other", owner=0, role=Role.TRAFFIC, x=5.0, y=0.0, heading=0.0)
    assert lead_rows(sim, agents).tolist() == [0, -1, -1]
    assert lead_rows(sim, agents).tolist() == [0, -1, -1]  # from the cache
    table.remove(0)
    table.add("stranger", owner=0, role=Role.TRAFFIC, x=9.0, y=0.0, heading=0.0)  # takes row 0
    assert lead_rows(sim, agents).tolist() == [-1, -1, -1]
    table.add("lead", owner=0, role=Role.TRAFFIC, x=1.0, y=0.0, heading=0.0)
    table.add("late", owner=0, role=Role.TRAFFIC, x=2.0, y=0.0, heading=0.0)
    assert lead_rows(sim, agents).tolist() == [2, -1, 3]
    assert lead_rows(sim, np.array([2, 0])).tolist() == [3, 2]
