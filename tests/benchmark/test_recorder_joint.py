"""The recorder against the simulation that produced the log: a scripted platoon episode on the
straight two-lane road (a follower that speeds up, changes lane and back, drifts off the road edge,
is turned round for a few steps and then reaches its goal), every log column compared with the
simulation's state captured at each step and with the quantity recomputed here from positions and
the road's geometry."""

from __future__ import annotations

import numpy as np
import pytest

from smarts.benchmark.recorder import EpisodeRecorder
from smarts.core.events import Event
from smarts.env import DrivingParallelEnv
from tests.builders import make_spec

LANE_WIDTH = 3.2
RIGHT_CENTRE, LEFT_CENTRE = -4.8, -1.6  # y of the two lane centres; the road runs along +x from x=0
GOAL_OFFSET = 100.0
DT = 0.1


def _script() -> list[tuple[float, float, float] | str]:
    """The follower's actions (dx, dy, dheading) and the ``"turn"`` marks (heading + pi)."""
    steps: list = [(1.0 + 0.03 * k, 0.0, 0.0) for k in range(8)]  # speeds up: 10 -> 12.1 m/s
    weave = [0.05] * 5 + [0.0] * 4 + [-0.05] * 5  # a lane change of about 2.7 m sideways
    steps += [(1.2, 0.0, dh) for dh in weave]  # to the left lane
    steps += [(1.2, 0.0, -dh) for dh in weave]  # and back
    steps += [(1.2, 0.0, dh) for dh in [-0.05] * 4 + [0.0] * 5 + [0.05] * 4]  # off the right edge
    steps += [(1.2, 0.0, dh) for dh in [0.05] * 4 + [0.0] * 5 + [-0.05] * 4]  # back on the road
    steps += ["turn", (1.2, 0.0, 0.0), (1.2, 0.0, 0.0), "turn"]  # three steps the wrong way
    steps += [(1.2, 0.0, 0.0)] * 40  # on to the goal
    return steps


def _episode(follow: bool = True):
    """The scripted episode; without ``follow`` the follower is a plain driver to its road goal."""
    agents = [
        {"id": "follower", "mission": {"start": {"road": "main", "offset": 10.0, "speed": 10.0},
                                       "goal": {"road": "main", "offset": GOAL_OFFSET},
                                       **({"follow": "lead"} if follow else {})}},
        {"id": "lead", "mission": {"start": {"road": "main", "offset": 25.0, "speed": 13.0}, "goal": {"endless": True}}},
    ]  # fmt: skip
    env = DrivingParallelEnv(make_spec(agents, events={"terminate_on": ["reached_goal"]}))
    env.reset(seed=0)
    sim, t = env.sim, env.sim.table
    recorder = EpisodeRecorder(sim, ["follower"], scenario="joint", task="adaptive", episode=0, seed=0,
                               time_limit=20.0)  # fmt: skip
    columns = ("x", "y", "heading", "speed", "accel", "jerk", "lat_accel", "t", "lane", "length")
    f, lead = sim.agent_row[0], sim.agent_row[1]
    reset = {c: float(getattr(t, c)[f]) for c in columns}
    before, after, lead_after, events = [], [], [], []

    def capture(sim):
        after.append({c: float(getattr(t, c)[f]) for c in columns})
        lead_after.append((float(t.x[lead]), float(t.length[lead])))
        events.append(sim.agent_events[0].copy())
        recorder.record()

    env.add_step_listener(capture)
    for action in _script():
        if "follower" not in env.agents:
            break
        if action == "turn":
            t.heading[f] = t.heading[f] + np.pi
            action = (1.2, 0.0, 0.0)
        before.append({c: float(getattr(t, c)[f]) for c in ("x", "y", "heading")})
        env.step({"follower": np.array(action), "lead": np.array([1.3, 0.0, 0.0])})
    log = recorder.finish()
    env.close()
    return log.agents["follower"], reset, before, after, lead_after, np.array(events), sim


@pytest.fixture(scope="module")
def episode():
    return _episode()


@pytest.fixture(scope="module")
def unled_episode():
    return _episode(follow=False)


def _col(after, name):
    return np.array([s[name] for s in after])


def test_one_row_per_step_until_the_goal(episode):
    trace, _, before, after, _, events, sim = episode
    n = len(after)
    assert len(trace.time) == n and n < len(_script()) - 10  # the goal ended it before the script did
    np.testing.assert_allclose(trace.time, DT * np.arange(1, n + 1), atol=1e-9)
    assert trace.goal_reached[-1] and not trace.goal_reached[:-1].any()
    assert after[-1]["x"] + 0.5 * after[-1]["length"] >= GOAL_OFFSET - 1.5  # near the goal line


def test_pose_columns_are_the_simulation_state(episode):
    trace, _, _, after, *_ = episode
    for name in ("x", "y", "heading", "speed"):
        np.testing.assert_array_equal(getattr(trace, name), _col(after, name), err_msg=name)
    np.testing.assert_array_equal(trace.accel_long, _col(after, "accel"))
    np.testing.assert_array_equal(trace.jerk_long, _col(after, "jerk"))
    np.testing.assert_array_equal(trace.accel_lat, _col(after, "lat_accel"))
    np.testing.assert_array_equal(trace.lane_offset, _col(after, "t"))


def test_kinematics_match_the_positions(episode):
    trace, reset, before, after, *_ = episode
    x0, y0, h0 = (np.array([s[c] for s in before]) for c in ("x", "y", "heading"))
    x, y, h = (_col(after, c) for c in ("x", "y", "heading"))
    speed = np.hypot(x - x0, y - y0) / DT
    np.testing.assert_allclose(trace.speed, speed, atol=1e-6)
    accel = np.diff(np.concatenate([[reset["speed"]], speed])) / DT
    np.testing.assert_allclose(trace.accel_long, accel, atol=1e-4)
    jerk = np.diff(np.concatenate([[reset["accel"]], accel])) / DT
    np.testing.assert_allclose(trace.jerk_long, jerk, atol=1e-2)
    yaw_rate = np.angle(np.exp(1j * (h - h0))) / DT
    lat = speed * yaw_rate
    np.testing.assert_allclose(trace.accel_lat, lat, atol=1e-4)
    lat_jerk = np.diff(np.concatenate([[reset["lat_accel"]], lat])) / DT
    np.testing.assert_allclose(trace.jerk_lat, lat_jerk, atol=1e-2)
    # The script exercised them: real accelerations and turns, not all zeros.
    assert np.abs(trace.accel_long).max() > 2.0 and np.abs(trace.jerk_long).max() > 10.0
    assert np.abs(trace.accel_lat).max() > 5.0 and np.abs(trace.jerk_lat).max() > 50.0


def _lane_of(y):
    """Lane centre y of the lane each y lies in, NaN off the road."""
    return np.where((y < -3.2) & (y >= -6.4), RIGHT_CENTRE, np.where((y >= -3.2) & (y <= 0.0), LEFT_CENTRE, np.nan))


def test_lane_columns_match_the_road_geometry(episode):
    trace, _, _, after, *_, sim = episode
    y = _col(after, "y")
    centre = _lane_of(y)
    on = ~np.isnan(centre)
    assert on.sum() > 40 and (centre == LEFT_CENTRE).sum() >= 5  # both lanes were driven
    np.testing.assert_allclose(trace.lane_offset[on], (y - centre)[on], atol=1e-6)
    np.testing.assert_allclose(trace.lane_width[on], LANE_WIDTH, atol=1e-9)
    limit = float(sim.road_map.lane_speed_limit[0])
    assert limit > 0 and (sim.road_map.lane_speed_limit == limit).all()
    np.testing.assert_allclose(trace.speed_limit, limit)


def test_route_distance_is_along_the_road_to_the_goal_plus_the_offset_from_the_route(unled_episode):
    trace, _, _, after, *_ = unled_episode
    x, y = _col(after, "x"), _col(after, "y")
    expected = np.maximum(GOAL_OFFSET - x, 0.0) + np.abs(y - RIGHT_CENTRE)
    np.testing.assert_allclose(trace.route_distance_to_goal, expected, atol=1e-6)


def test_a_followers_route_distance_runs_to_where_the_lead_ended(episode):
    trace, _, _, after, lead_after, *_ = episode
    x, y = _col(after, "x"), _col(after, "y")
    expected = lead_after[-1][0] - x + np.abs(y - RIGHT_CENTRE)
    # Measured to the nearest point of the sampled route path: within a sample spacing.
    np.testing.assert_allclose(trace.route_distance_to_goal, expected, atol=1.0)
    assert trace.route_distance_to_goal[7] < trace.route_distance_to_goal[0] - 6.0  # closing in


def test_following_columns_match_the_gap_to_the_lead(episode):
    trace, _, _, after, lead_after, *_ = episode
    x, y, speed = _col(after, "x"), _col(after, "y"), _col(after, "speed")
    lead_x, lead_len = np.array(lead_after).T
    gap = lead_x - x - 0.5 * (lead_len + _col(after, "length"))
    lane = _col(after, "lane")
    # The lane the simulation matched agrees with the road geometry wherever that is clear.
    clear = (np.abs(y - np.round(y / LANE_WIDTH) * LANE_WIDTH) > 0.1) & (y > -6.3)
    np.testing.assert_array_equal((lane == 0)[clear], (_lane_of(y) == RIGHT_CENTRE)[clear])
    in_lane = (lane == 0) & (gap > 0) & (gap < 50.0)
    np.testing.assert_array_equal(trace.lead_in_lane_and_visible, in_lane)
    assert in_lane.any() and not in_lane.all()
    excess = gap - (2.5 + 1.0 * speed)
    np.testing.assert_array_equal(trace.in_follow_margin, in_lane & (excess <= 0))
    assert (in_lane & (excess <= 0)).any() and (in_lane & (excess > 0)).any()
    expected = np.where(in_lane, np.maximum(excess, 0.0) / speed, np.nan)
    np.testing.assert_allclose(trace.follow_time_gap, expected, atol=1e-6, equal_nan=True)


def test_event_flags_are_the_simulation_events_and_the_geometry(episode):
    trace, _, _, after, _, events, _ = episode
    for flag, event in (("wrong_way", Event.WRONG_WAY), ("partial_off_road", Event.PARTIAL_OFF_ROAD),
                        ("off_road", Event.OFF_ROAD), ("goal_reached", Event.REACHED_GOAL)):  # fmt: skip
        np.testing.assert_array_equal(getattr(trace, flag), events[:, event], err_msg=flag)
        assert getattr(trace, flag).any(), f"the script never raised {flag}"
    heading, y = _col(after, "heading"), _col(after, "y")
    np.testing.assert_array_equal(trace.wrong_way, np.cos(heading) < 0)
    # A corner half a car width beyond the centre: clearly off where it passes the edge by 0.6 m.
    half_width = 0.95
    clearly_out = y - half_width * np.abs(np.cos(heading)) < -6.4 - 0.6
    clearly_in = y - 1.2 > -6.4 + 0.2
    assert clearly_out.any() and trace.partial_off_road[clearly_out].all()
    assert not trace.partial_off_road[clearly_in].any()
