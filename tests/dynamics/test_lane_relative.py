"""Lane-relative commands drive RelativeTargetPose, TargetPose and Continuous vehicles."""

import numpy as np
import pytest

from smarts.dynamics.action_spaces import ActionError
from smarts.dynamics.lane_relative import LaneRelativeParams
from smarts.env import DrivingParallelEnv
from smarts.scenario import scenario_to_yaml
from tests.builders import agent, make_spec

PARAMS = LaneRelativeParams()
LIMIT = 13.89  # the built-in maps' speed limit (m/s)


def hold(speed):
    """The speed command whose target is ``speed`` on a lane with the built-in limit."""
    return speed / LIMIT - 1.0


def _env(action_space="relative_target_pose", map_name="straight_3lane", **start):
    start = {"start_road": "main", "lane": 1, "offset": 10.0, "speed": 8.0, **start}
    spec = make_spec([agent(action_space=action_space, controller="lane_relative", **start)], map_name=map_name)
    env = DrivingParallelEnv(spec)
    env.reset(seed=0)
    return env


def _run(env, commands):
    """Step ``commands`` (a list of [accel, lane_change]); returns the agent row's history."""
    t, row = env.sim.table, env.sim.agent_row[0]
    rows = []
    for cmd in commands:
        env.step({"agent_0": np.asarray(cmd, dtype=np.float32)})
        rows.append((t.speed[row], t.accel[row], t.jerk[row], t.lat_accel[row], t.lane[row], t.t[row]))
    return np.array(rows)


def test_the_zero_command_cruises_at_the_limit_in_the_lane():
    env = _env()
    start_lane = env.sim.table.lane[env.sim.agent_row[0]]
    hist = _run(env, [[0.0, 0.0]] * 150)
    assert hist[-1, 0] == pytest.approx(LIMIT, abs=0.05)
    assert (hist[:, 4] == start_lane).all()
    assert np.abs(hist[:, 5]).max() < 1e-6
    assert env.action_space("agent_0").shape == (2,)


def test_a_speed_target_is_reached_within_the_acceleration_and_jerk_limits():
    env = _env()
    hist = _run(env, [[hold(8.0), 0.0]] * 10 + [[hold(12.0), 0.0]] * 100 + [[-1.0, 0.0]] * 150)
    np.testing.assert_allclose(hist[:10, 0], 8.0, atol=1e-9)  # the current speed as target: kept
    assert hist[109, 0] == pytest.approx(12.0, abs=0.05)
    # Comfortable jerk throughout, except while braking hard (the -1 command asks for it): never
    # when speeding up or easing off, and no jolt when the car comes to rest.
    jerky = np.flatnonzero(np.abs(hist[:, 2]) > PARAMS.max_jerk + 1e-6)
    assert jerky.size and (hist[jerky, 2] < 0).all() and (hist[jerky, 1] < 0).all()
    assert jerky.min() >= 110 and jerky.max() < 140  # during the hard stop, not as the car comes to rest
    assert np.abs(hist[:, 2]).max() <= PARAMS.brake_jerk + 1e-6
    assert hist[:, 1].max() <= PARAMS.max_accel + 1e-9 and hist[:, 1].min() >= -PARAMS.max_decel - 1e-9
    assert hist[-1, 0] < 0.02  # -1 brings it to rest
    dt = env.sim.dt
    assert hist[11, 1] == pytest.approx(2 * PARAMS.max_jerk * dt, abs=1e-6)  # the ramp at the jerk limit


@pytest.mark.parametrize("side, lane_id", [(1.0, "main_2"), (-1.0, "main_0")])
def test_a_lane_change_ends_centred_in_the_neighbour_lane_smoothly(side, lane_id):
    env = _env()
    steps = int(PARAMS.lane_change_time / env.sim.dt) + 10
    hist = _run(env, [[hold(8.0), side]] + [[hold(8.0), 0.0]] * steps)
    assert env.sim.road_map.lane_ids[int(hist[-1, 4])] == lane_id
    assert abs(hist[-1, 5]) < 0.05
    assert np.abs(hist[:, 3]).max() < 1.47  # lateral acceleration stays within the comfort limit
    first_turn = hist[np.flatnonzero(np.abs(hist[:, 3]) > 0.05)[0], 3]
    assert np.sign(first_turn) == side  # it first turns towards the side


def test_held_lane_change_changes_one_lane_at_a_time_and_never_leaves_the_road():
    env = _env(lane=0)
    hist = _run(env, [[hold(8.0), 1.0]] * 200)
    lanes = [env.sim.road_map.lane_ids[int(x)] for x in hist[:, 4]]
    first_left = lanes.index("main_1")
    assert "main_2" not in lanes[: first_left + int(PARAMS.lane_change_time / env.sim.dt) - 20]
    assert lanes[-1] == "main_2" and abs(hist[-1, 5]) < 0.05  # the leftmost lane: no further change
    assert not env.sim.agent_events[0].any()


def _exit_road(env, commands):
    row = env.sim.agent_row[0]
    rm, t = env.sim.road_map, env.sim.table
    for cmd in commands:
        env.step({"agent_0": np.asarray(cmd, dtype=np.float32)})
        if not env.agents:
            break
        road = rm.road_ids[rm.lane_road[t.lane[row]]]
    return road


@pytest.mark.parametrize("side, road", [(0.0, "east_out"), (1.0, "north_out"), (-1.0, "south_out")])
def test_a_request_towards_no_lane_picks_the_branch_at_the_junction(side, road):
    # A one-lane approach: left/right requests become the turn to take; none goes straight.
    env = _env(map_name="intersection_4way_1lane", start_road="west_in", lane=0, offset=40.0, speed=4.0)
    assert _exit_road(env, [[hold(4.0), side]] * 3 + [[hold(4.0), 0.0]] * 300) == road
    assert not (env.sim.agent_events[0][[0, 1, 2]]).any()  # no collision, off road or partial off road


def test_without_a_request_the_agent_follows_its_route_through_the_junction():
    spec = make_spec(
        [agent(start_road="west_in", lane=0, offset=40.0, speed=4.0, goal={"road": "south_out", "offset": 30},
               controller="lane_relative")],
        map_name="intersection_4way_1lane",
    )  # fmt: skip
    env = DrivingParallelEnv(spec)
    env.reset(seed=0)
    infos = {}
    for _ in range(300):
        _, _, _, _, infos = env.step({"agent_0": np.array([hold(4.0), 0.0], np.float32)})
        if not env.agents:
            break
    assert infos["agent_0"]["events"] == ["reached_goal"]


def test_target_pose_gives_the_same_motion_as_relative_target_pose():
    commands = [[0.3, 0.0]] * 10 + [[0.0, 1.0]] + [[-0.5, 0.0]] * 40
    a = _run(_env("relative_target_pose"), commands)
    b = _run(_env("target_pose"), commands)
    np.testing.assert_allclose(a, b, atol=1e-6)


def test_continuous_cars_keep_their_lane_accelerate_and_change_lanes():
    env = _env("continuous")
    hist = _run(env, [[hold(8.0), 0.0]] * 30)
    assert abs(hist[-1, 0] - 8.0) < 0.5 and np.abs(hist[:, 5]).max() < 0.3
    hist = _run(env, [[hold(12.0), 0.0]] * 80)
    assert abs(hist[-1, 0] - 12.0) < 1.0
    hist = _run(env, [[hold(12.0), -1.0]] + [[hold(12.0), 0.0]] * 80)
    assert env.sim.road_map.lane_ids[int(hist[-1, 4])] == "main_0" and abs(hist[-1, 5]) < 0.3
    env.close()


def test_bad_commands_name_the_agent_and_the_component_before_anything_moves():
    env = _env()
    row = env.sim.agent_row[0]
    x0 = env.sim.table.x[row]
    with pytest.raises(
        ActionError, match=r"agent_0: relative_target_pose \(lane_relative\) action component lane_change is nan"
    ):
        env.step({"agent_0": np.array([0.0, np.nan], np.float32)})
    with pytest.raises(ActionError, match=r"expected 2 \(speed, lane_change\)"):
        env.step({"agent_0": np.zeros(3, np.float32)})
    assert env.sim.table.x[row] == x0


def test_same_commands_same_trajectory():
    commands = [[np.sin(k / 7.0), 1.0 if k == 20 else 0.0] for k in range(120)]
    np.testing.assert_array_equal(_run(_env(), commands), _run(_env(), commands))


def test_params_are_validated():
    with pytest.raises(ValueError, match="max_jerk"):
        LaneRelativeParams(max_jerk=0.0)
    with pytest.raises(ValueError, match="threshold"):
        LaneRelativeParams(threshold=1.5)


def test_a_scenario_can_ask_for_the_controller_and_is_checked():
    from smarts.scenario import ScenarioError

    spec = make_spec([agent(controller="lane_relative")])
    assert spec.agents[0].controller == "lane_relative"
    assert "controller: lane_relative" in scenario_to_yaml(spec)
    with pytest.raises(ScenarioError, match=r"agents\[0\]\.controller: lane_relative drives"):
        make_spec([agent(action_space="lane", controller="lane_relative")])
    with pytest.raises(ScenarioError, match=r"agents\[0\]\.controller"):
        make_spec([agent(controller="autopilot")])


def test_the_projection_near_a_hint_equals_the_full_scan_whatever_the_hint():
    """The controller searches a lane near where the car was; a wrong hint must fall back to the
    whole lane, so the (s, t) found is always the full scan's (checked on every lane of a map with
    curves, junctions and long straights, for points on, beside and past the lanes)."""
    from smarts.dynamics.lane_relative import _project_near, _project_on_lane
    from smarts.maps import load_map
    from smarts.scenario import builtin_map_path

    rng = np.random.default_rng(0)
    for name in ("highway_merge_exit", "intersection_4way_2lane", "straight_3lane"):
        rm = load_map(builtin_map_path(name))
        off, pts, ps = rm.lanepoint_offsets, rm.lanepoints, rm.lanepoint_s
        for lane in range(rm.num_lanes):
            a, b = off[lane], off[lane + 1]
            if b - a < 2:
                continue
            for _ in range(6):
                k = rng.integers(a, b)
                x, y = pts[k] + rng.normal(0.0, 2.0, size=2)
                hint = rng.uniform(-50.0, ps[b - 1] + 50.0)  # anywhere, also far off
                full = _project_on_lane(off, pts, ps, lane, x, y)
                near = _project_near(off, pts, ps, lane, x, y, hint)
                assert near == pytest.approx(full, abs=1e-9), (name, lane, hint)
